#!/usr/bin/env python3
"""The fifth round of the fusion study (docs/ablation.md, "The fusion study, fifth round"): apply the
candidate rules v3, v3s, v4s (visibility arbitration only with sensor views) and the frozen decision
rule to the lines `cargo run --example fusion_study` wrote.

    python3 studies/fusion/fusion_study5.py --virtual D2,D3c,D4c,D5c --fresh D5,D5c D5=PATH D5c=PATH D1=PATH ...

--virtual names the sets whose depth views are a virtual pinhole trajectory (clouds only, built-in
frames); every other set has sensor views. --fresh names the development sets nobody had looked at when
the candidates were designed.
"""
from fusion_round import parse_args, report

RULES = ["v3", "v3s", "v4s"]
POSES = {
    "v3": ["union-b", "geometry", "noisy-and"],
    "v4": ["union-b", "geometry", "noisy-and", "image"],
}


def pick(rule, row, virtual):
    """(chosen pose, what decided it) for one row."""
    if rule in ("v3s", "v4s") and virtual:
        return "union-b", "virtual views"
    base = "v4" if rule == "v4s" else "v3"
    cands = row["candidates"]
    live = [n for n in POSES[base] if "error" not in cands[n]]
    if not live:
        return None, "none"
    best = max(cands[n]["vis"] for n in live)
    top = [n for n in live if cands[n]["vis"] == best]
    return top[0], ("V" if len(top) == 1 else "order")


if __name__ == "__main__":
    report(*parse_args(__doc__), RULES, pick, [("V", lambda c: str(c["vis"]))])
