#!/usr/bin/env python3
"""Pairs gained and lost by the `union` fusion against each branch alone and against the
paper's Noisy-AND, from the `cgenreg bench --json` outputs `scripts/fusion_eval.sh` writes:
OUT/<set>-union.json, <set>-noisy-and.json, <set>-image.json, <set>-geometry.json.

    python3 scripts/fusion_tables.py docs/results/fusion > docs/results/fusion/tables.md

Success is each run's own (`success` of a pair). A pair missing from a run (not run yet, or
failed) is listed, never counted as a success.
"""
import glob
import json
import os
import sys

MODES = [("geometry", "geometry alone"), ("image", "image alone"), ("noisy-and", "Noisy-AND")]
SETS = ["staged-clouds", "rgbd-3dlomatch", "lidar", "staged", "rgbd-3dmatch", "kitti07"]


def load(path):
    if not os.path.exists(path):
        return None
    d = json.load(open(path))
    return d


def main():
    out_dir = sys.argv[1]
    summary, detail = [], []
    for s in SETS:
        runs = {m: load(os.path.join(out_dir, f"{s}-{m}.json")) for m in ["union"] + [m for m, _ in MODES]}
        if runs["union"] is None:
            continue
        ids = [r["id"] for r in runs["union"]["pairs"]]
        rows = {m: ({r["id"]: r for r in d["pairs"]} if d else {}) for m, d in runs.items()}
        hdr = runs["union"]["run"]
        detail.append(f"### {s} (`{runs['union']['manifest']}`)\n")
        missing = {m: [i for i in ids if i not in rows[m] or rows[m][i].get("error")] for m in rows}
        for m, miss in missing.items():
            if miss:
                detail.append(f"- {m}: not run or failed: {', '.join(miss)}")
        detail.append("")
        detail.append("| pair | split | " + " | ".join(l for _, l in MODES) + " | union | union provenance |")
        detail.append("|---|---|---|---|---|---|---|")
        ok = lambda m, i: bool(rows[m].get(i, {}).get("success"))
        for i in ids:
            r = rows["union"][i]
            mk = lambda b: "ok" if b else "–"
            detail.append(f"| {i} | {r['split']} | " + " | ".join(mk(ok(m, i)) for m, _ in MODES)
                          + f" | {mk(ok('union', i))} | {(r.get('fusion') or r.get('error') or '').replace('|', '/')} |")
        detail.append("")
        detail.append("| against | pairs it registers | union registers | gained by union | lost by union |")
        detail.append("|---|---|---|---|---|")
        n = len(ids)
        nu = sum(ok("union", i) for i in ids)
        for m, label in MODES:
            if not runs[m]:
                detail.append(f"| {label} | not run | {nu}/{n} | | |")
                continue
            g = [i for i in ids if ok("union", i) and not ok(m, i)]
            l = [i for i in ids if ok(m, i) and not ok("union", i)]
            detail.append(f"| {label} | {sum(ok(m, i) for i in ids)}/{n} | {nu}/{n} | {len(g)} {' '.join(g)} | {len(l)} {' '.join(l)} |")
        detail.append("")
        either = [i for i in ids if ok("geometry", i) or ok("image", i)]
        below = [i for i in either if not ok("union", i)]
        cnt = lambda m: f"{sum(ok(m, i) for i in ids)}" if runs[m] else "not run"
        summary.append(f"| {s} | {n} | " + " | ".join(cnt(m) for m, _ in MODES)
                       + f" | {len(either)} | {nu} | {len(below)} {' '.join(below)} |")
    print("| set | pairs | geometry alone | image alone | Noisy-AND | either branch | union | pairs a branch registers and union does not |")
    print("|---|---|---|---|---|---|---|---|")
    print("\n".join(summary))
    print()
    print("\n".join(detail))


if __name__ == "__main__":
    main()
