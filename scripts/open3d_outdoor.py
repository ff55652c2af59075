#!/usr/bin/env python3
"""Open3D FPFH + RANSAC on the pairs of cgenreg dataset manifests (point-cloud fragments with
ground truth), printed in the columns of `cgenreg bench`'s per-pair table and written as JSON.

usage: open3d_outdoor.py [--voxel 0.3] [--seed 0] [--success RRE_DEG:RTE_M ...] [--json OUT.json]
                        MANIFEST.toml [...]

Protocol (docs/outdoor.md): voxel-downsample both clouds at v; normals radius 2 v (max 30
neighbours), FPFH radius 5 v (max 100); registration_ransac_based_on_feature_matching with the
mutual filter, inlier distance 1.5 v, point-to-point estimation, 3-point samples, edge-length
(0.9) and distance checkers, 100,000 iterations at confidence 0.999. Success: RRE <= 5 deg and
RTE <= 2 m (KITTI), with RRE <= 5 deg and RTE <= 0.6 m (SC2-PCR's KITTI criterion) beside it;
--success (repeatable) replaces them, e.g. `--success 15:0.3` for the indoor (3DMatch) criterion.
Ground truth is target_from_source (p_target = T * p_source), as in the manifests.
Run it through scripts/open3d_outdoor.sh, which makes the scratch venv.
"""
import argparse
import json
import os
import platform
import sys
import time
import tomllib

import numpy as np
import open3d as o3d

CRITERIA = [(5.0, 2.0), (5.0, 0.6)]


def expand(s):
    if "$CGENREG_DATA" in s or "${CGENREG_DATA}" in s:
        root = os.environ.get("CGENREG_DATA")
        if not root:
            sys.exit("set CGENREG_DATA to the data folder (the manifests' root)")
        s = s.replace("${CGENREG_DATA}", root).replace("$CGENREG_DATA", root)
    return os.path.expandvars(s)


def read_cloud(path, fields):
    if not path.endswith(".bin"):
        pc = o3d.io.read_point_cloud(path)
        return np.asarray(pc.points, dtype=np.float64)
    raw = np.fromfile(path, dtype=np.float32)
    if fields is None:
        fields = 4 if raw.size % 4 == 0 and raw.size % 3 != 0 else 3
    return raw.reshape(-1, fields)[:, :3].astype(np.float64)


def read_gt(pair, root):
    if "gt_matrix" in pair:
        return np.array(pair["gt_matrix"], dtype=np.float64)
    if "gt_file" in pair:
        return np.loadtxt(os.path.join(root, expand(pair["gt_file"])), dtype=np.float64)
    return None


def rre_deg(est, gt):
    c = (np.trace(est[:3, :3].T @ gt[:3, :3]) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


def rte_m(est, gt):
    return float(np.linalg.norm(gt[:3, 3] - est[:3, 3]))


def fpfh(points, v):
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    pc = pc.voxel_down_sample(v)
    pc.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=2 * v, max_nn=30))
    f = o3d.pipelines.registration.compute_fpfh_feature(
        pc, o3d.geometry.KDTreeSearchParamHybrid(radius=5 * v, max_nn=100))
    return pc, f


def register(src, tgt, v, seed):
    reg = o3d.pipelines.registration
    o3d.utility.random.seed(seed)
    s, fs = fpfh(src, v)
    t, ft = fpfh(tgt, v)
    d = 1.5 * v
    r = reg.registration_ransac_based_on_feature_matching(
        s, t, fs, ft, True, d,
        reg.TransformationEstimationPointToPoint(False), 3,
        [reg.CorrespondenceCheckerBasedOnEdgeLength(0.9),
         reg.CorrespondenceCheckerBasedOnDistance(d)],
        reg.RANSACConvergenceCriteria(100000, 0.999))
    return np.asarray(r.transformation), len(s.points), len(t.points)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("manifests", nargs="+")
    ap.add_argument("--voxel", type=float, default=0.3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--success", action="append", metavar="RRE_DEG:RTE_M",
                    help="success criterion (repeatable); default 5:2 and 5:0.6")
    ap.add_argument("--json")
    a = ap.parse_args()
    criteria = CRITERIA
    if a.success:
        try:
            criteria = [tuple(float(x) for x in c.split(":", 1)) for c in a.success]
            if any(len(c) != 2 for c in criteria):
                raise ValueError
        except ValueError:
            ap.error(f"--success: expected RRE_DEG:RTE_M (e.g. 15:0.3), got {a.success}")
    o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
    rows = []
    for m in a.manifests:
        with open(m, "rb") as fh:
            man = tomllib.load(fh)
        root = os.path.join(os.path.dirname(os.path.abspath(m)), expand(man.get("root", ".")))
        frags = {f["id"]: f for f in man["fragments"]}
        clouds = {}
        for p in man["pairs"]:
            gt = read_gt(p, root)
            if gt is None:
                continue
            for k in (p["source"], p["target"]):
                if k not in clouds:
                    f = frags[k]
                    clouds[k] = read_cloud(os.path.join(root, expand(f["cloud"])),
                                           f.get("kitti_fields"))
            t0 = time.perf_counter()
            est, ns, nt = register(clouds[p["source"]], clouds[p["target"]], a.voxel, a.seed)
            dt = time.perf_counter() - t0
            rre, rte = rre_deg(est, gt), rte_m(est, gt)
            rows.append({
                "id": f"{man['name']}/{p['target']}-{p['source']}",
                "split": p.get("split", ""),
                "gt_distance_m": float(np.linalg.norm(gt[:3, 3])),
                "rre_deg": rre, "rte_m": rte,
                "success": [rre <= r and rte <= t for r, t in criteria],
                "keypoints": [ns, nt],
                "time_s": dt,
            })
            print(f"{rows[-1]['id']}: RRE {rre:.2f} deg, RTE {rte:.3f} m, {dt:.1f} s",
                  file=sys.stderr)
    print(f"Open3D {o3d.__version__} FPFH + RANSAC, voxel {a.voxel} m, seed {a.seed}")
    print("| pair | distance m | RRE ° | RTE m | "
          + "".join(f"success {r_:g}°/{t_:g}m | " for r_, t_ in criteria) + "s |")
    print("|---" * (5 + len(criteria)) + "|")
    yn = {True: "yes", False: "no"}
    for r in rows:
        print(f"| {r['id']} | {r['gt_distance_m']:.1f} | {r['rre_deg']:.2f} | {r['rte_m']:.3f} | "
              + "".join(f"{yn[ok]} | " for ok in r["success"]) + f"{r['time_s']:.2f} |")
    n = len(rows)
    for i, (r_, t_) in enumerate(criteria):
        k = sum(r["success"][i] for r in rows)
        print(f"registered at RRE <= {r_:g}°, RTE <= {t_:g} m: {k}/{n}")
    if n:
        print(f"mean s/pair: {sum(r['time_s'] for r in rows) / n:.2f}")
    if a.json:
        out = {
            "method": "Open3D FPFH + RANSAC (mutual filter, 100000 iterations, confidence 0.999)",
            "open3d": o3d.__version__,
            "python": platform.python_version(),
            "voxel_m": a.voxel,
            "ransac_distance_m": 1.5 * a.voxel,
            "seed": a.seed,
            "criteria": [{"max_rre_deg": r_, "max_rte_m": t_} for r_, t_ in criteria],
            "manifests": [os.path.basename(m) for m in a.manifests],
            "pairs": rows,
        }
        with open(a.json, "w") as fh:
            json.dump(out, fh, indent=1)
        print(f"wrote {a.json}", file=sys.stderr)


if __name__ == "__main__":
    main()
