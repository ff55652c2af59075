"""Worked example: the staged 3DMatch pairs and the KITTI 07 ladder from Python, compared with
Open3D's FPFH + RANSAC in the same script when Open3D is installed, and a failure opened in the
inspector.

    export CGENREG_DATA=/path/to/shared/data
    python examples/python/register_staged.py            # geometric branch, every pair
    python examples/python/register_staged.py --open3d   # + Open3D FPFH + RANSAC per pair
    python examples/python/register_staged.py --inspect  # open the first failure in the GUI

Success: 3DMatch's RRE <= 15 deg and RTE <= 0.30 m (the library's own flag); KITTI's
RRE < 5 deg and RTE < 2 m (the odometry benchmark's registration criterion).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

import cgenreg

REPO = Path(__file__).resolve().parents[2]
STAGED = REPO / "assets" / "manifests" / "redkitchen-staged.toml"


def rre_rte(t: np.ndarray, gt: np.ndarray):
    """Rotation error (deg) and translation error (m) of the estimate `t` against `gt`."""
    r = gt[:3, :3].T @ t[:3, :3]
    cos = np.clip((np.trace(r) - 1.0) / 2.0, -1.0, 1.0)
    return float(np.degrees(np.arccos(cos))), float(np.linalg.norm(t[:3, 3] - gt[:3, 3]))


def open3d_fpfh_ransac(src: np.ndarray, tgt: np.ndarray, voxel: float) -> np.ndarray:
    """Open3D's usual pipeline: voxel downsampling, normals (2v), FPFH (5v), feature-matching
    RANSAC (distance 1.5v, 100k iterations, 0.999 confidence); returns target_from_source."""
    import open3d as o3d

    reg = o3d.pipelines.registration

    def prep(p):
        pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(p))
        pc = pc.voxel_down_sample(voxel)
        pc.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=2 * voxel, max_nn=30))
        f = reg.compute_fpfh_feature(
            pc, o3d.geometry.KDTreeSearchParamHybrid(radius=5 * voxel, max_nn=100)
        )
        return pc, f

    (ps, fs), (pt, ft) = prep(src), prep(tgt)
    d = 1.5 * voxel
    r = reg.registration_ransac_based_on_feature_matching(
        ps, pt, fs, ft, True, d,
        reg.TransformationEstimationPointToPoint(False), 3,
        [reg.CorrespondenceCheckerBasedOnEdgeLength(0.9), reg.CorrespondenceCheckerBasedOnDistance(d)],
        reg.RANSACConvergenceCriteria(100000, 0.999),
    )
    return np.asarray(r.transformation)


def kitti_pairs(root: Path):
    """(target, source, gt) of kitti07-lidar/gt_pairs.txt (target_from_source)."""
    lines = [l for l in (root / "kitti07-lidar" / "gt_pairs.txt").read_text().splitlines()
             if l.strip() and not l.startswith("#")]
    for k in range(0, len(lines), 5):
        t, s = lines[k].split()[:2]
        gt = np.array([[float(v) for v in l.split()] for l in lines[k + 1:k + 5]])
        yield int(t), int(s), gt


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--open3d", action="store_true", help="also run Open3D FPFH + RANSAC")
    ap.add_argument("--inspect", action="store_true", help="open the first failure in the inspector")
    ap.add_argument("--kitti-voxel", type=float, default=0.3)
    a = ap.parse_args()
    root = Path(os.environ.get("CGENREG_DATA", REPO.parent / "shared" / "data"))
    if not root.is_dir():
        print("set CGENREG_DATA to the data folder", file=sys.stderr)
        return 1
    os.environ["CGENREG_DATA"] = str(root)
    failures = []

    print("== staged 3DMatch pairs (voxel 0.05 m)")
    ok = ok_o3d = 0
    pairs = cgenreg.manifest_pairs(STAGED)
    for p in pairs:
        t0 = time.perf_counter()
        res = cgenreg.register_pair(STAGED, p["id"], voxel=0.05)
        dt = time.perf_counter() - t0
        ok += bool(res.success)
        line = "%-18s %-9s RRE %7.2f deg  RTE %6.3f m  %s  %.2f s" % (
            p["id"], p["split"], res.rre_deg, res.rte_m, "ok  " if res.success else "FAIL", dt)
        if not res.success:
            failures.append(("manifest", p["id"]))
        if a.open3d:
            s_pts, t_pts = _fragment_clouds(root, p)
            t0 = time.perf_counter()
            t = open3d_fpfh_ransac(s_pts, t_pts, 0.05)
            rre, rte = rre_rte(t, p["gt"])
            good = rre <= 15.0 and rte <= 0.30
            ok_o3d += good
            line += "  | Open3D RRE %7.2f RTE %6.3f %s %.2f s" % (
                rre, rte, "ok  " if good else "FAIL", time.perf_counter() - t0)
        print(line)
    print("cgenreg: %d/%d registered" % (ok, len(pairs))
          + ("; Open3D FPFH + RANSAC: %d/%d" % (ok_o3d, len(pairs)) if a.open3d else ""))

    print("== KITTI 07 ladder (voxel %.2f m; success RRE < 5 deg, RTE < 2 m)" % a.kitti_voxel)
    ok = ok_o3d = n = 0
    kd = root / "kitti07-lidar"
    # these scans are x, y, z only (12 bytes a point; the folder's MANIFEST.md); some sizes fit
    # both KITTI layouts, and the reader refuses to guess
    os.environ["CGENREG_KITTI_FIELDS"] = "3"
    for t, s, gt in kitti_pairs(root):
        n += 1
        src, tgt = kd / ("keyframe-%d.bin" % s), kd / ("keyframe-%d.bin" % t)
        t0 = time.perf_counter()
        res = cgenreg.register(src, tgt, gt, voxel=a.kitti_voxel)
        dt = time.perf_counter() - t0
        rre, rte = rre_rte(res.target_from_source, gt)
        good = rre < 5.0 and rte < 2.0
        ok += good
        line = "%d <- %d  RRE %7.2f deg  RTE %6.3f m  %s  %.2f s" % (
            t, s, rre, rte, "ok  " if good else "FAIL", dt)
        if not good:
            failures.append(("files", (src, tgt, gt, a.kitti_voxel)))
        if a.open3d:
            t0 = time.perf_counter()
            to3 = open3d_fpfh_ransac(cgenreg.read_cloud(src), cgenreg.read_cloud(tgt), a.kitti_voxel)
            r3, t3 = rre_rte(to3, gt)
            g3 = r3 < 5.0 and t3 < 2.0
            ok_o3d += g3
            line += "  | Open3D RRE %7.2f RTE %6.3f %s %.2f s" % (
                r3, t3, "ok  " if g3 else "FAIL", time.perf_counter() - t0)
        print(line)
    print("cgenreg: %d/%d registered" % (ok, n)
          + ("; Open3D FPFH + RANSAC: %d/%d" % (ok_o3d, n) if a.open3d else ""))

    if a.inspect and failures:
        kind, what = failures[0]
        if kind == "manifest":
            cgenreg.inspect(STAGED, what, voxel=0.05, wait=True)
        else:
            src, tgt, gt, v = what
            cgenreg.inspect(source=src, target=tgt, gt=gt, voxel=v, wait=True)
    return 0


def _fragment_clouds(root: Path, p):
    """The full clouds of a staged pair's fragments, read by cgenreg's readers (the manifest's
    files), for Open3D."""
    import re

    text = STAGED.read_text()
    clouds = dict(re.findall(r'id = "([^"]+)"\ncloud = "([^"]+)"', text))
    return (cgenreg.read_cloud(root / clouds[p["source"]]),
            cgenreg.read_cloud(root / clouds[p["target"]]))


if __name__ == "__main__":
    sys.exit(main())
