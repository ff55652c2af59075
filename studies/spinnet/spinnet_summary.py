#!/usr/bin/env python3
"""Collect the runs of studies/spinnet/spinnet_bench.sh into studies/spinnet/results/.

    python3 studies/spinnet/spinnet_summary.py [BENCH_DIR]   # default target/spinnet-bench

Copies each run file (`cgenreg bench --json`) as it is, except that a manifest path under this
repository is written relative to it (the run files of the first runs named it absolutely), and
writes `summary.json`: per run the pairs, successes, median RRE / RTE, the wall and CPU time and the
peak memory that /usr/bin/time measured, and per SpinNet run the time per described scan; plus the
ONNX-vs-torch figures of target/spinnet/report.json when present. BENCHMARKS.md's tables are made
from the copied run files by scripts/tables.py.
"""
import json
import os
import re
import shutil
import statistics
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
RUNS = ["dev-fpfh", "dev-spinnet-128", "dev-spinnet-256", "kitti-fpfh", "kitti-spinnet-128",
        "staged-fpfh", "staged-spinnet-128", "kitti-spinnet-512-probe",
        "staged-fpfh-oracle", "staged-spinnet-128-oracle", "rgbd-fpfh", "rgbd-spinnet-128",
        "rgbd-fpfh-oracle", "rgbd-spinnet-128-oracle", "kitti-fpfh-builtin", "kitti-spinnet-128-builtin",
        # the evaluated rows at 256, the count chosen on every development pair (KEYPOINTS=256)
        "kitti-spinnet-256", "staged-spinnet-256", "staged-spinnet-256-oracle", "rgbd-spinnet-256",
        "rgbd-spinnet-256-oracle", "kitti-spinnet-256-builtin"]


def relative(d):
    for where in (d, (d.get("run") or {}).get("identity") or {}):
        m = where.get("manifest")
        if isinstance(m, str) and m.startswith(ROOT + os.sep):
            where["manifest"] = os.path.relpath(m, ROOT)
    return d


def timing(path):
    """'%e s wall, %U s user, %S s system, %M kB peak RSS' (older runs: wall and RSS only)."""
    if not os.path.exists(path):
        return {}
    text = open(path).read()
    out = {}
    for key, pat in [("wall_s", r"([\d.]+) s wall"), ("user_s", r"([\d.]+) s user"),
                     ("system_s", r"([\d.]+) s system"), ("peak_rss_mb", r"(\d+) kB peak RSS")]:
        m = re.search(pat, text)
        if m:
            out[key] = float(m.group(1)) / (1024 if key == "peak_rss_mb" else 1)
    if "peak_rss_mb" in out:
        out["peak_rss_mb"] = round(out["peak_rss_mb"], 1)
    return out


def main():
    bench = sys.argv[1] if len(sys.argv) > 1 else os.path.join(ROOT, "target", "spinnet-bench")
    dest = os.path.join(ROOT, "studies", "spinnet", "results")
    os.makedirs(dest, exist_ok=True)
    summary = {"runs": {}, "note": "geometry only (SC2-PCR, nearest-neighbour selection) unless a run's name ends "
               "in -oracle or -builtin (the image branch with ALIKE-t and the default fusion); SpinNet at the "
               "keypoint count in its name (128: chosen on the development pair; 256: on every development pair, the "
               "default); times on a 2-core machine shared with other "
               "work (wall) and the process's own CPU time (user)"}
    # runs of an earlier bench folder that this one does not hold keep their committed entry
    old_path = os.path.join(dest, "summary.json")
    old = json.load(open(old_path)).get("runs", {}) if os.path.exists(old_path) else {}
    # the optional steps' runs, by name
    extra = sorted(
        f[:-5] for f in os.listdir(bench) if f.endswith(".json") and f[:-5] not in RUNS
        and re.match(r"(repose-|dev-all-|staged-.*-builtin$|rgbd-.*-builtin$)", f[:-5])
    ) if os.path.isdir(bench) else []
    for name in RUNS + extra + sorted(k for k in old if k not in RUNS and k not in extra):
        src = os.path.join(bench, name + ".json")
        done = os.path.join(bench, name + ".time")
        # a run still going has its .json (rewritten after every pair) but no timing yet
        if not os.path.exists(src) or not os.path.exists(done) or os.path.getsize(done) == 0:
            if name in old:
                summary["runs"][name] = old[name]
            continue
        d = relative(json.load(open(src)))
        with open(os.path.join(dest, name + ".json"), "w") as f:
            json.dump(d, f, indent=1)
            f.write("\n")
        pairs = d["pairs"]
        ok = [p for p in pairs if p.get("success")]
        row = {
            "pairs": len(pairs),
            "registered": len(ok),
            "geo_features": d["params"]["geo_features"],
            "median_rre_deg_registered": round(statistics.median(p["rre_deg"] for p in ok), 3) if ok else None,
            "median_rte_cm_registered": round(100 * statistics.median(p["rte_m"] for p in ok), 2) if ok else None,
            "per_pair": {p["id"]: {"success": p.get("success"), "rre_deg": p.get("rre_deg"),
                                   "rte_m": p.get("rte_m"), "error": p.get("error")} for p in pairs},
        }
        row.update(timing(os.path.join(bench, name + ".time")))
        if d["params"]["geo_features"].get("kind") == "spinnet":
            scans = {p[k] for p in pairs for k in ("source", "target")}
            row["scans_described"] = len(scans)
            if "wall_s" in row:
                row["wall_s_per_scan"] = round(row["wall_s"] / len(scans), 1)
            if "user_s" in row:
                row["cpu_s_per_scan"] = round((row["user_s"] + row.get("system_s", 0)) / len(scans), 1)
        summary["runs"][name] = row
    chosen = os.path.join(bench, "chosen.txt")
    if os.path.exists(chosen):
        summary["keypoints_chosen"] = open(chosen).read().strip()
    elif os.path.exists(old_path):
        prev = json.load(open(old_path))
        for key in ("keypoints_chosen", "export"):
            if key in prev:
                summary[key] = prev[key]
    report = os.path.join(ROOT, "target", "spinnet", "report.json")
    if os.path.exists(report):
        r = json.load(open(report))
        summary["export"] = {"torch": r["torch"], "onnxruntime": r["onnxruntime"], "models": {
            k: {x: v[x] for x in ("checkpoint", "checkpoint_sha256", "onnx_bytes", "max_abs_diff_onnx_vs_torch",
                                  "max_abs_descriptor", "min_cosine_onnx_vs_torch", "cloud", "keypoint_indices")}
            for k, v in r["models"].items()}}
    with open(os.path.join(dest, "summary.json"), "w") as f:
        json.dump(summary, f, indent=1)
        f.write("\n")
    print(json.dumps({k: {x: v.get(x) for x in ("pairs", "registered", "wall_s", "user_s", "peak_rss_mb",
                                                   "wall_s_per_scan", "cpu_s_per_scan")}
                      for k, v in summary["runs"].items()}, indent=1))


if __name__ == "__main__":
    main()
