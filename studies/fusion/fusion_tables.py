#!/usr/bin/env python3
"""Pairs gained and lost by the default fusion (`visibility`) against each branch alone, the
paper's Noisy-AND and the `union` fusion, from the `cgenreg bench --json` outputs
`studies/fusion/fusion_eval.sh` writes: OUT/<set>-visibility.json, <set>-union.json,
<set>-noisy-and.json, <set>-image.json, <set>-geometry.json.

    python3 studies/fusion/fusion_tables.py studies/fusion/results/eval > studies/fusion/results/eval/tables.md

Success is each run's own (`success` of a pair). A pair missing from a run (not run yet, or
failed) is listed, never counted as a success.
"""
import json
import os
import sys

MODES = [("geometry", "geometry alone"), ("image", "image alone"), ("noisy-and", "Noisy-AND"),
         ("union", "union")]
DEFAULT = "visibility"
SETS = ["staged-clouds", "rgbd-3dlomatch", "lidar", "staged", "staged-builtin", "rgbd-3dmatch", "kitti07",
        "revisit", "revisit-clouds"]


def load(path):
    if not os.path.exists(path):
        return None
    return json.load(open(path))


def main():
    out_dir = sys.argv[1]
    summary, detail = [], []
    for s in SETS:
        runs = {m: load(os.path.join(out_dir, f"{s}-{m}.json")) for m in [DEFAULT] + [m for m, _ in MODES]}
        if runs[DEFAULT] is None:
            continue
        ids = [r["id"] for r in runs[DEFAULT]["pairs"]]
        rows = {m: ({r["id"]: r for r in d["pairs"]} if d else {}) for m, d in runs.items()}
        detail.append(f"### {s} (`{runs[DEFAULT]['manifest']}`)\n")
        detail.append(f"Default run: `{runs[DEFAULT]['run'].get('command', '')}`\n"
                      if runs[DEFAULT].get("run", {}).get("command") else "")
        missing = {m: [i for i in ids if i not in rows[m] or rows[m][i].get("error")] for m in rows}
        for m, miss in missing.items():
            if miss:
                detail.append(f"- {m}: not run or failed: {', '.join(miss)}")
        detail.append("")
        detail.append("| pair | split | " + " | ".join(l for _, l in MODES) + " | visibility (default) | its provenance |")
        detail.append("|---" * (4 + len(MODES)) + "|")
        ok = lambda m, i: bool(rows[m].get(i, {}).get("success"))
        mk = lambda b: "ok" if b else "–"
        for i in ids:
            r = rows[DEFAULT][i]
            detail.append(f"| {i} | {r['split']} | " + " | ".join(mk(ok(m, i)) for m, _ in MODES)
                          + f" | {mk(ok(DEFAULT, i))} | {(r.get('fusion') or r.get('error') or '').replace('|', '/')} |")
        detail.append("")
        detail.append("| against | pairs it registers | visibility registers | gained by visibility | lost by visibility |")
        detail.append("|---|---|---|---|---|")
        n = len(ids)
        nv = sum(ok(DEFAULT, i) for i in ids)
        for m, label in MODES:
            if not runs[m]:
                detail.append(f"| {label} | not run | {nv}/{n} | | |")
                continue
            g = [i for i in ids if ok(DEFAULT, i) and not ok(m, i)]
            l = [i for i in ids if ok(m, i) and not ok(DEFAULT, i)]
            detail.append(f"| {label} | {sum(ok(m, i) for i in ids)}/{n} | {nv}/{n} | {len(g)} {' '.join(g)} | {len(l)} {' '.join(l)} |")
        detail.append("")
        either = [i for i in ids if ok("geometry", i) or ok("image", i) or ok("noisy-and", i)]
        below = [i for i in either if not ok(DEFAULT, i)]
        cnt = lambda m: f"{sum(ok(m, i) for i in ids)}" if runs[m] else "not run"
        summary.append(f"| {s} | {n} | " + " | ".join(cnt(m) for m, _ in MODES)
                       + f" | {len(either)} | {nv} | {len(below)} {' '.join(below)} |")
    print("| set | pairs | geometry alone | image alone | Noisy-AND | union | a single branch | visibility (default) | pairs a single branch registers and visibility does not |")
    print("|---|---|---|---|---|---|---|---|---|")
    print("\n".join(summary))
    print()
    print("\n".join(detail))


if __name__ == "__main__":
    main()
