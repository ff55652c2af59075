#!/usr/bin/env python3
"""The sixth round of the fusion study (docs/ablation.md, "The fusion study, sixth round"): apply the
candidate rules v3s (the present default), f3s, f4s and f4 (the Wilson lower bound of the share of seen
keypoints that are consistent) and the frozen decision rule to the lines `cargo run --example
fusion_study` wrote.

    python3 studies/fusion/fusion_study6.py --virtual D2,D3c,D4c,D5c,D6c --fresh D6,D6c D6=PATH D6c=PATH D1=PATH ...

--virtual names the sets whose depth views are a virtual pinhole trajectory (clouds only, built-in
frames); every other set has sensor views. --fresh names the development sets nobody had looked at when
the candidates were designed.
"""
import math

from fusion_round import parse_args, report

RULES = ["v3s", "f3s", "f4s", "f4"]
THREE = ["union-b", "geometry", "noisy-and"]
Z = 1.96


def share(c):
    """F: the Wilson lower bound (z = 1.96) of consistent / (consistent + conflicting), both
    directions summed; 0 when no keypoint is seen."""
    good = c["vis_st"][0] + c["vis_ts"][0]
    n = good + c["vis_st"][1] + c["vis_ts"][1]
    if n == 0:
        return 0.0
    p = good / n
    return (p + Z * Z / (2 * n) - Z * math.sqrt(p * (1 - p) / n + Z * Z / (4 * n * n))) / (1 + Z * Z / n)


def pick(rule, row, virtual):
    """(chosen pose, what decided it) for one row."""
    if rule != "f4" and virtual:
        return "union-b", "virtual views"
    names = THREE + (["image"] if rule in ("f4s", "f4") else [])
    score = (lambda c: c["vis"]) if rule == "v3s" else share
    cands = row["candidates"]
    live = [n for n in names if "error" not in cands[n]]
    if not live:
        return None, "none"
    best = max(score(cands[n]) for n in live)
    top = [n for n in live if score(cands[n]) == best]
    return top[0], (("V" if rule == "v3s" else "F") if len(top) == 1 else "order")


if __name__ == "__main__":
    report(*parse_args(__doc__), RULES, pick,
           [("V", lambda c: str(c["vis"])), ("F", lambda c: f"{share(c):.4f}")])
