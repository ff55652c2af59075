#!/usr/bin/env python3
"""Pairs gained and lost by the `consensus` fusion against each branch alone and against the
paper's Noisy-AND, from `cgenreg bench --json` outputs of runs with `--fusion consensus` (each
pair's result records every candidate's pose and errors, so one run gives all four rows).

    python3 scripts/fusion_tables.py docs/results/fusion/*.json > docs/results/fusion/tables.md

Success is the run's own (`success` of each candidate and of the pair).
"""
import json
import os
import sys

BRANCHES = [("geometry", "geometry alone"), ("image", "image alone"), ("noisy-and", "Noisy-AND")]


def main():
    out = []
    summary = []
    for path in sys.argv[1:]:
        d = json.load(open(path))
        rows = d["pairs"]
        name = os.path.basename(path)
        out.append(f"### {name} (`{d['manifest']}`)\n")
        missing = [r["id"] for r in rows if not r.get("consensus")]
        if missing:
            out.append(f"Pairs without a consensus decision (failed or another mode): {', '.join(missing)}\n")
        rows = [r for r in rows if r.get("consensus")]
        out.append("| pair | split | " + " | ".join(b[1] for b in BRANCHES) + " | consensus | chose | decided by | inliers on the union (geometry / Noisy-AND / image) |")
        out.append("|---|---|---|---|---|---|---|---|---|")
        n_ok = {b: 0 for b, _ in BRANCHES}
        n_ok["consensus"] = 0
        gained = {b: [] for b, _ in BRANCHES}
        lost = {b: [] for b, _ in BRANCHES}
        for r in rows:
            c = {x["candidate"]: x for x in r["consensus"]["candidates"]}
            ok = {b: bool(c.get(b, {}).get("success")) for b, _ in BRANCHES}
            mine = bool(r.get("success"))
            n_ok["consensus"] += mine
            for b, _ in BRANCHES:
                n_ok[b] += ok[b]
                if mine and not ok[b]:
                    gained[b].append(r["id"])
                if ok[b] and not mine:
                    lost[b].append(r["id"])
            m = lambda v: "ok" if v else "–"
            fits = " / ".join(str(c[b]["fit"]["consensus"]) if b in c else "–" for b, _ in BRANCHES)
            out.append(f"| {r['id']} | {r['split']} | " + " | ".join(m(ok[b]) for b, _ in BRANCHES)
                       + f" | {m(mine)} | {r['consensus']['chosen']} | {r['consensus']['decided_by']} | {fits} |")
        n = len(rows)
        out.append("")
        out.append("| against | its registered pairs | consensus | gained | lost |")
        out.append("|---|---|---|---|---|")
        for b, label in BRANCHES:
            out.append(f"| {label} | {n_ok[b]}/{n} | {n_ok['consensus']}/{n} | {len(gained[b])} {' '.join(gained[b])} | {len(lost[b])} {' '.join(lost[b])} |")
        out.append("")
        either = [r for r in rows
                  if any(x.get("success") for x in r["consensus"]["candidates"] if x["candidate"] in ("geometry", "image"))]
        below = [r["id"] for r in either if not r.get("success")]
        summary.append(f"| {name} | {n} | " + " | ".join(f"{n_ok[b]}" for b, _ in BRANCHES)
                       + f" | {len(either)} | {n_ok['consensus']} | {len(below)} {' '.join(below)} |")
    print("| run | pairs | geometry alone | image alone | Noisy-AND | either branch | consensus | pairs lost against a branch |")
    print("|---|---|---|---|---|---|---|---|")
    print("\n".join(summary))
    print()
    print("\n".join(out))


if __name__ == "__main__":
    main()
