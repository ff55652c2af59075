"""Benchmark of the Python package, in one run:

1. the overhead of a Python call over the command line on the same pairs: the wall time of
   `cgenreg.register_pair(...)` around the call (option parsing, the registration, the result
   turned into NumPy arrays and JSON) against the command line's own `total_ms` (the
   registration inside `cgenreg register --json`), both without the pair's loading (its "load
   pair" timing row);
2. FPFH + SC2-PCR from Python (`cgenreg.fpfh`, `cgenreg.match_then_fuse`, `cgenreg.sc2pcr`)
   against Open3D's FPFH + RANSAC from Python on the staged pairs: time and pairs registered.

    CGENREG_DATA=... python examples/python/bench_python.py --cli target/release/cgenreg \
        --profile release --json docs/results/python/bench-release.json

Needs the `cgenreg` binary built in the same profile as the extension, and Open3D for part 2.
`--json` writes what it printed (the tables of docs/python.md are made from it by
scripts/tables.py), with the command, the machine and the date.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

import cgenreg

sys.path.insert(0, str(Path(__file__).resolve().parent))
from register_staged import STAGED, _fragment_clouds, open3d_fpfh_ransac, rre_rte  # noqa: E402


def load_ms(timings) -> float:
    return sum(ms for stage, ms, _ in timings if stage == "load pair")


def overhead(cli: str, pairs, reps: int):
    rows = []
    for p in pairs:
        c, y = [], []
        for _ in range(reps):  # alternate, so that machine load falls on both alike
            out = subprocess.run(
                [cli, "register", "--manifest", str(STAGED), "--pair", p, "--no-cache", "--json"],
                check=True, capture_output=True, text=True,
            )
            r = json.loads(out.stdout)
            c.append(r["total_ms"] - sum(t["ms"] for t in r["timings"] if t["stage"] == "load pair"))
            t0 = time.perf_counter()
            res = cgenreg.register_pair(STAGED, p, no_cache=True)
            wall = (time.perf_counter() - t0) * 1e3
            y.append(wall - load_ms(res.timings))
        rows.append((p, statistics.median(c), statistics.median(y)))
        print("%-18s CLI %8.1f ms  Python %8.1f ms  (%+.1f %%)" % (
            p, rows[-1][1], rows[-1][2], 100 * (rows[-1][2] / rows[-1][1] - 1)), flush=True)
    tc, ty = sum(r[1] for r in rows), sum(r[2] for r in rows)
    print("total: CLI %.1f ms, Python %.1f ms: overhead %+.2f %%" % (tc, ty, 100 * (ty / tc - 1)))
    return [{"pair": p, "cli_ms": round(c, 1), "python_ms": round(y, 1)} for p, c, y in rows]


def stages_vs_open3d(root: Path, voxel: float, with_o3d: bool):
    n = ok = ok3 = 0
    t_ours = t_o3d = 0.0
    per_pair = []
    for p in cgenreg.manifest_pairs(STAGED):
        src, tgt = _fragment_clouds(root, p)
        t0 = time.perf_counter()
        kp_s, f_s = cgenreg.fpfh(src, voxel)
        kp_t, f_t = cgenreg.fpfh(tgt, voxel)
        i, j, s = cgenreg.match_then_fuse(f_s, f_t)
        est = cgenreg.sc2pcr(kp_s[i], kp_t[j], s)
        dt = time.perf_counter() - t0
        rre, rte = rre_rte(est.target_from_source, p["gt"])
        good = rre <= 15.0 and rte <= 0.30
        n += 1
        ok += good
        t_ours += dt
        line = "%-18s cgenreg %6.2f s %s" % (p["id"], dt, "ok  " if good else "FAIL")
        row = {"pair": p["id"], "cgenreg_s": round(dt, 3), "cgenreg_ok": bool(good)}
        if with_o3d:
            t0 = time.perf_counter()
            t = open3d_fpfh_ransac(src, tgt, voxel)
            d3 = time.perf_counter() - t0
            r3, e3 = rre_rte(t, p["gt"])
            g3 = r3 <= 15.0 and e3 <= 0.30
            ok3 += g3
            t_o3d += d3
            line += " | Open3D %6.2f s %s" % (d3, "ok  " if g3 else "FAIL")
            row.update({"open3d_s": round(d3, 3), "open3d_ok": bool(g3)})
        per_pair.append(row)
        print(line, flush=True)
    print("cgenreg FPFH + SC2-PCR: %d/%d registered, %.2f s" % (ok, n, t_ours))
    if with_o3d:
        print("Open3D FPFH + RANSAC:  %d/%d registered, %.2f s (%.2fx cgenreg's time)" % (
            ok3, n, t_o3d, t_o3d / t_ours))
    return per_pair


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--cli", required=True, help="the cgenreg binary (same build profile)")
    ap.add_argument("--pairs", nargs="*", default=["redkitchen/0-1", "redkitchen/5-6", "redkitchen/21-34"])
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--skip-overhead", action="store_true")
    ap.add_argument("--profile", default="dev", help="the build profile of binary and extension (a label)")
    ap.add_argument("--json", help="also write the results here")
    a = ap.parse_args()
    root = Path(os.environ.get("CGENREG_DATA", Path(__file__).resolve().parents[3] / "shared" / "data"))
    os.environ["CGENREG_DATA"] = str(root)
    try:
        import open3d

        o3d = "Open3D %s" % open3d.__version__
    except ImportError:
        o3d = None
    machine = "%s, %d CPUs; Python %s; numpy %s; %s" % (
        platform.processor() or platform.machine(), os.cpu_count(), platform.python_version(),
        np.__version__, o3d or "no Open3D")
    date = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    print("machine: %s; %s" % (machine, date))
    repo = Path(__file__).resolve().parents[2]
    argv = [os.path.relpath(x, repo) if os.path.isabs(x) and x.startswith(str(repo)) else x
            for x in sys.argv[1:]]
    out = {"command": " ".join(["python", "examples/python/bench_python.py"] + argv),
           "profile": a.profile, "machine": machine, "date": date, "reps": a.reps}
    if not a.skip_overhead:
        print("== Python call overhead over the CLI (median of %d, loading excluded)" % a.reps)
        out["overhead"] = overhead(a.cli, a.pairs, a.reps)
    print("== FPFH + SC2-PCR from Python vs Open3D FPFH + RANSAC from Python (voxel 0.05 m)")
    out["staged"] = stages_vs_open3d(root, 0.05, o3d is not None)
    if a.json:
        os.makedirs(os.path.dirname(os.path.abspath(a.json)), exist_ok=True)
        with open(a.json, "w") as f:
            json.dump(out, f, indent=1)
            f.write("\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
