#!/usr/bin/env python3
"""Success counts of studies/repose/repose_study.sh's runs, per row and seed, with the original frame's
row beside them: python3 studies/repose/repose_summary.py REPOSE_DIR ORIGINAL_DIR
(ORIGINAL_DIR holds the un-moved rows, e.g. studies/ablation/results/vfm-per-pixel: fpfh-nn.json,
alike-oracle-noisy-and.json, alike-oracle-image.json). 'Success' is the JSON's own (3DMatch
thresholds: RRE <= 15 deg, RTE <= 30 cm). Also lists, per pair, in how many frames each row succeeds."""
import glob
import json
import os
import re
import sys

rdir, odir = sys.argv[1], sys.argv[2]
ROWS = ["fpfh-nn", "alike-oracle-image", "alike-oracle-noisy-and"]


def successes(path):
    v = json.load(open(path))
    return {r["id"]: bool(r.get("result") and r["result"].get("success"))
            for r in v["records"] if r.get("result", {}).get("split") == "3DLoMatch"}


seeds = sorted({int(m.group(1)) for f in glob.glob(os.path.join(rdir, "*-seed*.json"))
                for m in [re.search(r"-seed(\d+)\.json$", f)] if m})
runs = {}
for row in ROWS:
    runs[row] = {"orig": successes(os.path.join(odir, row + ".json"))}
    for s in seeds:
        p = os.path.join(rdir, f"{row}-seed{s}.json")
        if os.path.exists(p):
            got = successes(p)
            if len(got) == len(runs[row]["orig"]):
                runs[row][s] = got
cols = ["orig"] + seeds
print("| row (3DLoMatch, 10 pairs) | original frame | " + " | ".join(f"seed {s}" for s in seeds) + " | mean over seeds |")
print("|---|---|" + "---|" * len(seeds) + "---|")
for row in ROWS:
    cells, vals = [], []
    for c in cols:
        r = runs[row].get(c)
        cells.append("–" if r is None else str(sum(r.values())))
        if r is not None and c != "orig":
            vals.append(sum(r.values()))
    mean = f"{sum(vals) / len(vals):.1f} ({len(vals)} seeds)" if vals else "–"
    print(f"| {row} | " + " | ".join(cells) + f" | {mean} |")
print()
ids = sorted(runs[ROWS[0]]["orig"])
print("| pair | " + " | ".join(f"{row}: frames ok (of {1 + sum(1 for c in seeds if c in runs[row])})" for row in ROWS) + " |")
print("|---|" + "---|" * len(ROWS))
for i in ids:
    print(f"| {i.split('/')[-1]} | " + " | ".join(
        str(sum(1 for c in cols if c in runs[row] and runs[row][c].get(i))) for row in ROWS) + " |")
