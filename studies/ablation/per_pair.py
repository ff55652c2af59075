#!/usr/bin/env python3
"""Per-pair RRE / RTE / inlier ratio of several `cgenreg bench --json` files, side by side, for
one split: python3 studies/ablation/per_pair.py SPLIT FILE.json... (a column group per file, named by
the file's stem; 'ok' = the 3DMatch success test RRE <= 15 deg and RTE <= 30 cm)."""
import json
import os
import sys

split, files = sys.argv[1], sys.argv[2:]
runs = []
for f in files:
    v = json.load(open(f))
    if "records" in v:  # the run files of the first ablation runs
        rows = {r["id"]: r["result"] for r in v["records"] if r.get("result")}
    else:  # `cgenreg bench --json` now: one row per pair
        rows = {r["id"]: r for r in v["pairs"]}
    runs.append((os.path.basename(f).removesuffix(".json"), rows))
ids = [i for i, r in runs[0][1].items() if r.get("split") == split]
print("| pair | " + " | ".join(f"{n}: RRE° / RTE cm / IR % / ok" for n, _ in runs) + " |")
print("|---|" + "---|" * len(runs))
for i in ids:
    cells = []
    for _, rows in runs:
        r = rows.get(i)
        if not r or r.get("rre_deg") is None:
            cells.append("–")
            continue
        cells.append("%.1f / %.1f / %.1f / %s" % (r["rre_deg"], 100 * r["rte_m"],
                                                  100 * r["inlier_ratio"],
                                                  "**ok**" if r["success"] else "no"))
    print(f"| {i.split('/')[-1]} | " + " | ".join(cells) + " |")
