#!/usr/bin/env python3
"""The peers a user would pick instead of cgenreg, on the pairs of cgenreg dataset manifests:
KISS-Matcher (PyPI `kiss-matcher`) and Open3D FPFH + RANSAC (PyPI `open3d-cpu`), printed in the
columns of `cgenreg bench`'s per-pair table and written as JSON.

usage: peers.py [--method kiss|open3d|all] [--voxel V] [--seed 0] [--success RRE_DEG:RTE_M ...]
                [--pairs SUBSTRING ...] [--json OUT.json] MANIFEST.toml [...]

Run it through scripts/peers.sh, which makes the scratch venv.

Pairs: every pair with ground truth whose two fragments are cloud files (.ply .pcd .npy .bin
.pth .xyz); pairs of fragments built from RGB-D frames are skipped (named on stderr). `--pairs`
(repeatable) keeps the pairs whose id contains one of the given strings.

Voxel: --voxel, else the manifest's preset: 0.05 m indoors (3DMatch), 0.3 m outdoors (KITTI).
Success: --success (repeatable), else the preset's criteria: RRE <= 15 deg and RTE <= 0.3 m
indoors; RRE <= 5 deg and RTE <= 2 m outdoors (KITTI), with SC2-PCR's 5 deg / 0.6 m beside it.
Ground truth is target_from_source (p_target = T * p_source), as in the manifests.

KISS-Matcher: `KISSMatcherConfig(voxel)` with every other setting at its default, then
`KISSMatcher.estimate(source, target)`, as in the package's own example. Its estimate varies from
run to run (threads; OMP_NUM_THREADS=1 does not fix it): a pair near a threshold may pass in one
run and fail in the next, so a figure is one run's.

Open3D (the protocol of docs/outdoor.md): voxel-downsample both clouds at v; normals radius 2 v
(max 30 neighbours), FPFH radius 5 v (max 100); registration_ransac_based_on_feature_matching
with the mutual filter, inlier distance 1.5 v, point-to-point estimation, 3-point samples,
edge-length (0.9) and distance checkers, 100,000 iterations at confidence 0.999.

Times per pair: `time_s` is the estimate alone from clouds in memory (every step of the method:
downsampling, normals, features, matching, solver); `load_s` reads both cloud files;
`total_s` = load + estimate, the whole pair. Single-threaded runs: set OMP_NUM_THREADS.

JSON: one method gives one object (the fields below); `--method all` gives
{"command", "commit", "machine", "date", "runs": [one object per method]}. Each object: method,
command, commit, machine, date, versions, voxel_m, seed, criteria, manifests, pairs (id, split, gt_distance_m,
rre_deg, rte_m, success [one per criterion], keypoints, load_s, time_s, total_s).
"""
import argparse
import datetime
import io
import json
import os
import pickle
import platform
import shlex
import socket
import subprocess
import sys
import time
import tomllib
import warnings

import numpy as np

INDOOR = {"voxel": 0.05, "criteria": [(15.0, 0.3)]}
OUTDOOR = {"voxel": 0.3, "criteria": [(5.0, 2.0), (5.0, 0.6)]}
CLOUD_EXT = (".ply", ".pcd", ".npy", ".bin", ".pth", ".pkl", ".xyz", ".txt")


def protocol(preset):
    return OUTDOOR if preset and preset.startswith("outdoor") else INDOOR


def expand(s):
    if "$CGENREG_DATA" in s or "${CGENREG_DATA}" in s:
        root = os.environ.get("CGENREG_DATA")
        if not root:
            sys.exit("set CGENREG_DATA to the data folder (the manifests' root)")
        s = s.replace("${CGENREG_DATA}", root).replace("$CGENREG_DATA", root)
    return os.path.expandvars(s)


class _ArrayUnpickler(pickle.Unpickler):
    """Only what a pickled NumPy array needs: nothing else in a .pth file can run code."""

    ALLOWED = {("numpy.core.multiarray", "_reconstruct"), ("numpy._core.multiarray", "_reconstruct"),
               ("numpy", "ndarray"), ("numpy", "dtype"), ("collections", "OrderedDict"),
               ("_codecs", "encode")}  # protocol-2 pickles store bytes through it

    def find_class(self, module, name):
        if (module, name) not in self.ALLOWED:
            raise pickle.UnpicklingError(f"{module}.{name} is not allowed in a point-cloud file")
        with warnings.catch_warnings():  # NumPy 2 reads numpy.core through a deprecated alias
            warnings.simplefilter("ignore", DeprecationWarning)
            return super().find_class(module, name)

    def persistent_load(self, pid):
        raise pickle.UnpicklingError("tensor storages are not supported: expected a NumPy array")


def read_pth(path):
    """A legacy torch.save file of a NumPy array (five concatenated pickles: magic number,
    protocol, system info, the object, storage keys; the fourth is the array), or one pickle."""
    with open(path, "rb") as fh:
        data = fh.read()
    f = io.BytesIO(data)
    objs = []
    while f.tell() < len(data) and len(objs) < 5:
        objs.append(_ArrayUnpickler(f).load())
    arr = next((o for o in (objs[3:4] if len(objs) >= 4 else objs) if isinstance(o, np.ndarray)), None)
    if arr is None:
        arr = next((o for o in objs if isinstance(o, np.ndarray)), None)
    if arr is None or arr.ndim != 2 or arr.shape[1] < 3:
        raise ValueError(f"{path}: expected an (N, 3) array in the pickle, got {type(arr).__name__}")
    return np.ascontiguousarray(arr[:, :3], dtype=np.float64)


def read_cloud(path, fields):
    ext = os.path.splitext(path)[1].lower()
    if ext == ".bin":
        raw = np.fromfile(path, dtype=np.float32)
        if fields is None:
            fields = int(os.environ.get("CGENREG_KITTI_FIELDS", 0)) or (
                4 if raw.size % 4 == 0 and raw.size % 3 != 0 else 3)
        return raw.reshape(-1, fields)[:, :3].astype(np.float64)
    if ext in (".pth", ".pkl"):
        return read_pth(path)
    if ext == ".npy":
        a = np.load(path, allow_pickle=False)
        return np.ascontiguousarray(a.reshape(-1, a.shape[-1])[:, :3], dtype=np.float64)
    if ext in (".xyz", ".txt"):
        return np.loadtxt(path, dtype=np.float64, ndmin=2)[:, :3]
    import open3d as o3d
    pc = o3d.io.read_point_cloud(path)
    if len(pc.points) == 0:
        raise ValueError(f"{path}: no points read")
    return np.asarray(pc.points, dtype=np.float64)


def read_gt_log(path):
    """gt.log: `i j N` then a 4x4 T with p_i = T p_j; keyed by (i, j)."""
    out = {}
    with open(path) as fh:
        lines = [line.split() for line in fh if line.strip()]
    for k in range(0, len(lines) - 4, 5):
        i, j = int(lines[k][0]), int(lines[k][1])
        out[(i, j)] = np.array([[float(x) for x in lines[k + r]] for r in range(1, 5)])
    return out


_GT_LOGS = {}


def read_gt(pair, root):
    if "gt_matrix" in pair:
        return np.array(pair["gt_matrix"], dtype=np.float64)
    if "gt_file" in pair:
        return np.loadtxt(os.path.join(root, expand(pair["gt_file"])), dtype=np.float64)
    if "gt_log" in pair:
        path = os.path.join(root, expand(pair["gt_log"]))
        if path not in _GT_LOGS:
            _GT_LOGS[path] = read_gt_log(path)
        key = tuple(pair["gt_entry"]) if "gt_entry" in pair else (int(pair["target"]), int(pair["source"]))
        return _GT_LOGS[path].get(key)
    return None


def rre_deg(est, gt):
    c = (np.trace(est[:3, :3].T @ gt[:3, :3]) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


def rte_m(est, gt):
    return float(np.linalg.norm(gt[:3, 3] - est[:3, 3]))


class Open3d:
    name = "open3d"

    def __init__(self, voxel, seed):
        import open3d as o3d
        self.o3d, self.v, self.seed = o3d, voxel, seed
        o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
        self.label = "Open3D FPFH + RANSAC (mutual filter, 100000 iterations, confidence 0.999)"
        self.versions = {"open3d": o3d.__version__}

    def _fpfh(self, points):
        o3d, v = self.o3d, self.v
        pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
        pc = pc.voxel_down_sample(v)
        pc.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=2 * v, max_nn=30))
        f = o3d.pipelines.registration.compute_fpfh_feature(
            pc, o3d.geometry.KDTreeSearchParamHybrid(radius=5 * v, max_nn=100))
        return pc, f

    def register(self, src, tgt):
        reg = self.o3d.pipelines.registration
        self.o3d.utility.random.seed(self.seed)
        s, fs = self._fpfh(src)
        t, ft = self._fpfh(tgt)
        d = 1.5 * self.v
        r = reg.registration_ransac_based_on_feature_matching(
            s, t, fs, ft, True, d,
            reg.TransformationEstimationPointToPoint(False), 3,
            [reg.CorrespondenceCheckerBasedOnEdgeLength(0.9),
             reg.CorrespondenceCheckerBasedOnDistance(d)],
            reg.RANSACConvergenceCriteria(100000, 0.999))
        return np.asarray(r.transformation), [len(s.points), len(t.points)], {}

    def settings(self):
        return {"ransac_distance_m": 1.5 * self.v}


class Kiss:
    name = "kiss"

    def __init__(self, voxel, seed):
        import kiss_matcher
        from importlib.metadata import version
        self.km, self.v = kiss_matcher, voxel
        self.label = "KISS-Matcher (KISSMatcherConfig(voxel), every other setting at its default)"
        self.versions = {"kiss-matcher": version("kiss-matcher")}

    def register(self, src, tgt):
        m = self.km.KISSMatcher(self.km.KISSMatcherConfig(self.v))
        r = m.estimate(src.astype(np.float32), tgt.astype(np.float32))
        est = np.eye(4)
        est[:3, :3] = np.asarray(r.rotation, dtype=np.float64)
        est[:3, 3] = np.asarray(r.translation, dtype=np.float64).reshape(3)
        kp = [len(x) for x in m.get_processed_input_clouds()] if hasattr(
            m, "get_processed_input_clouds") else []
        return est, kp, {"valid": bool(r.valid), "final_inliers": int(m.get_num_final_inliers())}

    def settings(self):
        return {}


METHODS = {"kiss": Kiss, "open3d": Open3d}


def load_pairs(manifests, filters):
    """(manifest name, pair id, split, preset, source path+fields, target path+fields, gt)."""
    out = []
    for m in manifests:
        with open(m, "rb") as fh:
            man = tomllib.load(fh)
        root = os.path.join(os.path.dirname(os.path.abspath(m)), expand(man.get("root", ".")))
        frags = {f["id"]: f for f in man.get("fragments", [])}
        for p in man.get("pairs", []):
            pid = f"{man['name']}/{p['target']}-{p['source']}"
            if filters and not any(f in pid for f in filters):
                continue
            ends = [frags.get(p["source"]), frags.get(p["target"])]
            if any(f is None or "cloud" not in f for f in ends):
                print(f"{pid}: skipped (a fragment without a cloud file)", file=sys.stderr)
                continue
            paths = [os.path.join(root, expand(f["cloud"])) for f in ends]
            if not all(x.lower().endswith(CLOUD_EXT) for x in paths):
                print(f"{pid}: skipped (not a cloud file: {paths})", file=sys.stderr)
                continue
            gt = read_gt(p, root)
            if gt is None:
                print(f"{pid}: skipped (no ground truth)", file=sys.stderr)
                continue
            out.append({"manifest": m, "id": pid, "split": p.get("split", ""),
                        "preset": p.get("preset", man.get("preset", "indoor")),
                        "clouds": [(x, f.get("kitti_fields")) for x, f in zip(paths, ends)],
                        "gt": gt})
    return out


def commit():
    """The repository's commit, "+dirty" when the working tree differs from it."""
    here = os.path.dirname(os.path.abspath(__file__))
    try:
        rev = subprocess.run(["git", "-C", here, "rev-parse", "HEAD"], capture_output=True,
                             text=True, check=True).stdout.strip()
        dirty = subprocess.run(["git", "-C", here, "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True, check=True).stdout.strip()
        return rev + ("+dirty" if dirty else "")
    except (OSError, subprocess.CalledProcessError):
        return None


def machine():
    cpu = ""
    try:
        with open("/proc/cpuinfo") as fh:
            cpu = next((l.split(":", 1)[1].strip() for l in fh if l.startswith("model name")), "")
    except OSError:
        pass
    return {"host": socket.gethostname(), "cpu": cpu, "cores": os.cpu_count(),
            "platform": platform.platform(), "omp_num_threads": os.environ.get("OMP_NUM_THREADS")}


def run_method(cls, pairs, a, criteria_for, voxel_for, header):
    rows = []
    methods = {}
    for p in pairs:
        v = voxel_for(p)
        if v not in methods:
            methods[v] = cls(v, a.seed)
        meth = methods[v]
        t0 = time.perf_counter()
        src, tgt = (read_cloud(*c) for c in p["clouds"])
        t1 = time.perf_counter()
        est, kp, extra = meth.register(src, tgt)
        t2 = time.perf_counter()
        gt = p["gt"]
        rre, rte = rre_deg(est, gt), rte_m(est, gt)
        crit = criteria_for(p)
        row = {"id": p["id"], "split": p["split"],
               "gt_distance_m": float(np.linalg.norm(gt[:3, 3])),
               "rre_deg": rre, "rte_m": rte,
               "success": [rre <= r and rte <= t for r, t in crit],
               "keypoints": kp, "load_s": t1 - t0, "time_s": t2 - t1, "total_s": t2 - t0,
               "target_from_source": est.tolist()}
        row.update(extra)
        rows.append(row)
        print(f"{meth.name} {p['id']}: RRE {rre:.2f} deg, RTE {rte:.3f} m, {t2 - t1:.2f} s",
              file=sys.stderr)
    meth = next(iter(methods.values()), None) or cls(a.voxel or INDOOR["voxel"], a.seed)
    voxels = sorted(methods) or [a.voxel]
    out = dict(header)
    out.update({
        "method": meth.label,
        "versions": dict(meth.versions, python=platform.python_version(), numpy=np.__version__),
        "voxel_m": voxels[0] if len(voxels) == 1 else voxels,
        "seed": a.seed,
        "criteria": [{"max_rre_deg": r, "max_rte_m": t} for r, t in
                     (criteria_for(pairs[0]) if pairs else [])],
        "manifests": [os.path.basename(m) for m in a.manifests],
        "pairs": rows,
    })
    out.update(meth.settings())
    if "open3d" in meth.versions:  # the field names earlier Open3D result files use
        out["open3d"] = meth.versions["open3d"]
        out["python"] = platform.python_version()
    print_table(out)
    return out


def print_table(out):
    rows, crits = out["pairs"], out_criteria(out)
    print(f"{out['method']} {', '.join(f'{k} {v}' for k, v in out['versions'].items())}, "
          f"voxel {out['voxel_m']} m, seed {out['seed']}")
    print("| pair | distance m | RRE ° | RTE m | "
          + "".join(f"success {r_:g}°/{t_:g}m | " for r_, t_ in crits) + "s |")
    print("|---" * (5 + len(crits)) + "|")
    yn = {True: "yes", False: "no"}
    for r in rows:
        print(f"| {r['id']} | {r['gt_distance_m']:.1f} | {r['rre_deg']:.2f} | {r['rte_m']:.3f} | "
              + "".join(f"{yn[ok]} | " for ok in r["success"]) + f"{r['time_s']:.2f} |")
    n = len(rows)
    for split in sorted({r["split"] for r in rows}):
        sub = [r for r in rows if r["split"] == split]
        for i, (r_, t_) in enumerate(crits):
            ok = [r for r in sub if r["success"][i]]
            line = f"{split or 'all'}: registered at RRE <= {r_:g}°, RTE <= {t_:g} m: {len(ok)}/{len(sub)}"
            if ok:
                line += (f"; mean RE {np.mean([r['rre_deg'] for r in ok]):.2f}°, "
                         f"mean TE {100 * np.mean([r['rte_m'] for r in ok]):.1f} cm")
            print(line)
    if n:
        print(f"mean s/pair: estimate {np.mean([r['time_s'] for r in rows]):.2f}, "
              f"whole pair {np.mean([r['total_s'] for r in rows]):.2f}")


def out_criteria(out):
    return [(c["max_rre_deg"], c["max_rte_m"]) for c in out["criteria"]]


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("manifests", nargs="+")
    ap.add_argument("--method", choices=["kiss", "open3d", "all"], default="all")
    ap.add_argument("--voxel", type=float, help="default: 0.05 m indoors, 0.3 m outdoors")
    ap.add_argument("--seed", type=int, default=0, help="Open3D's RANSAC seed")
    ap.add_argument("--success", action="append", metavar="RRE_DEG:RTE_M",
                    help="success criterion (repeatable); default: the manifest's preset's")
    ap.add_argument("--pairs", action="append", metavar="SUBSTRING",
                    help="keep pairs whose id contains this (repeatable)")
    ap.add_argument("--json")
    a = ap.parse_args()
    fixed = None
    if a.success:
        try:
            fixed = [tuple(float(x) for x in c.split(":", 1)) for c in a.success]
            if any(len(c) != 2 for c in fixed):
                raise ValueError
        except ValueError:
            ap.error(f"--success: expected RRE_DEG:RTE_M (e.g. 15:0.3), got {a.success}")
    if a.voxel is not None and not a.voxel > 0:
        ap.error(f"--voxel: expected a positive size in metres, got {a.voxel}")
    pairs = load_pairs(a.manifests, a.pairs)
    if not pairs:
        sys.exit("peers: no pair with ground truth and cloud files in " + " ".join(a.manifests))

    def criteria_for(p):
        return fixed or protocol(p["preset"])["criteria"]

    def voxel_for(p):
        return a.voxel or protocol(p["preset"])["voxel"]

    header = {
        "command": " ".join(shlex.quote(x) for x in
                            [os.environ.get("PEERS_COMMAND", "scripts/peers.sh")] + sys.argv[1:]),
        "commit": commit(),
        "machine": machine(),
        "date": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
    }
    names = ["kiss", "open3d"] if a.method == "all" else [a.method]
    runs = [run_method(METHODS[n], pairs, a, criteria_for, voxel_for, header) for n in names]
    if a.json:
        out = runs[0] if len(runs) == 1 else dict(header, runs=runs)
        tmp = a.json + ".tmp"
        with open(tmp, "w") as fh:
            json.dump(out, fh, indent=1)
        os.replace(tmp, a.json)
        print(f"wrote {a.json}", file=sys.stderr)


if __name__ == "__main__":
    main()
