#!/usr/bin/env python3
"""Compare two bench JSONs pair by pair: every number and string except timings and
provenance (time_s, stage ms, created/host fields). Prints one line per file and every
difference; exits 1 when any differs.

usage: bench_compare.py BASELINE_DIR NEW_DIR NAME.json [NAME.json ...]
"""
import json
import sys

SKIP = {"time_s", "ms", "time_per_pair_s", "created_unix", "host", "started_unix",
        "finished_unix", "elapsed_s", "cache_dir", "json", "binary", "pid", "run_id"}


def walk(a, b, path, out):
    if isinstance(a, dict) and isinstance(b, dict):
        for k in sorted(set(a) | set(b)):
            if k in SKIP:
                continue
            if k not in a or k not in b:
                out.append(f"{path}.{k}: only in {'new' if k in b else 'baseline'}")
                continue
            walk(a[k], b[k], f"{path}.{k}", out)
    elif isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            out.append(f"{path}: {len(a)} vs {len(b)} items")
        for i, (x, y) in enumerate(zip(a, b)):
            walk(x, y, f"{path}[{i}]", out)
    elif a != b:
        out.append(f"{path}: {a!r} vs {b!r}")


def main():
    base, new, names = sys.argv[1], sys.argv[2], sys.argv[3:]
    bad = 0
    for n in names:
        a = json.load(open(f"{base}/{n}"))
        b = json.load(open(f"{new}/{n}"))
        out = []
        stage_diffs = {}
        # Per pair: the result (all fields but time), and the stage list (names, not times or
        # cache status: the baseline ran on warm caches in places).
        pa = {p["id"]: p for p in a["pairs"]}
        pb = {p["id"]: p for p in b["pairs"]}
        if sorted(pa) != sorted(pb):
            out.append(f"pair ids differ: {sorted(pa)} vs {sorted(pb)}")
        for pid in sorted(set(pa) & set(pb)):
            walk(pa[pid], pb[pid], f"pairs[{pid}]", out)
        ra = {r["id"]: r for r in a["records"]}
        rb = {r["id"]: r for r in b["records"]}
        for pid in sorted(set(ra) & set(rb)):
            walk(ra[pid].get("result"), rb[pid].get("result"), f"records[{pid}].result", out)
            sa = [s["stage"] for s in ra[pid].get("stages", [])]
            sb = [s["stage"] for s in rb[pid].get("stages", [])]
            if sa != sb:
                stage_diffs.setdefault((tuple(sa), tuple(sb)), []).append(pid)
        walk(a["summary"], b["summary"], "summary", out)
        walk(a["params"], b["params"], "params", out)
        for (sa, sb), pids in stage_diffs.items():
            out.append(f"stage names of {len(pids)} pairs (labels, not numbers): "
                       f"{list(sa)} vs {list(sb)}")
        npairs = len(set(pa) & set(pb))
        nnum = sum(1 for p in pa.values() for k, v in p.items()
                   if isinstance(v, (int, float)) and not isinstance(v, bool) and k not in SKIP)
        same = sum(1 for pid in set(pa) & set(pb) for k, v in pa[pid].items()
                   if k not in SKIP and pb[pid].get(k) == v)
        print(f"{n}: {npairs} pairs; per-pair fields equal: {same} of "
              f"{sum(1 for p in pa.values() for k in p if k not in SKIP)} ({nnum} numbers: rre_deg, "
              f"rte_m, inlier_ratio per pair); other differences: {len(out) or 'none'}")
        for o in out:
            print(f"  {o}")
        bad += len(out)
    sys.exit(1 if bad else 0)


if __name__ == "__main__":
    main()
