#!/usr/bin/env python3
"""The fourth round of the fusion study (docs/ablation.md, "The fusion study, fourth round"):
apply the candidate rules b, v2, v3, v4 (visibility consistency as the arbiter) and the frozen
decision rule to the lines `cargo run --example fusion_study` wrote.

    python3 studies/fusion/fusion_study4.py D4=studies/fusion/results/dev/vis-D4.jsonl D4c=... D3=... ...

Optional EARLIER=NAME=PATH arguments name an earlier round's lines of the same pairs: a pair whose
single-branch results (geometry, image, Noisy-AND, union registered or not) differ is listed.
"""
import json
import sys

from fusion_study import SINGLE, load_sets, ok

RULES = ["b", "v2", "v3", "v4"]
COST = {"b": 1, "v2": 2, "v3": 3, "v4": 4}
POSES = {
    "b": ["union-b"],
    "v2": ["union-b", "noisy-and"],
    "v3": ["union-b", "geometry", "noisy-and"],
    "v4": ["union-b", "geometry", "noisy-and", "image"],
}


def choose(rule, row):
    """(name of the chosen pose, what decided it): the largest V, ties by the order."""
    cands = row["candidates"]
    live = [n for n in POSES[rule] if "error" not in cands[n]]
    if not live:
        return None, "none"
    if len(live) == 1:
        return live[0], "-"
    best = max(cands[n]["vis"] for n in live)
    top = [n for n in live if cands[n]["vis"] == best]
    return top[0], ("V" if len(top) == 1 else "order")


def rule_ok(rule, row):
    n, why = choose(rule, row)
    return (ok(row["candidates"][n]) if n else False), n, why


def compare_earlier(sets, earlier):
    """Pairs whose registered / not registered per branch differs from an earlier round's line."""
    out = []
    for name, path in earlier.items():
        old = {}
        for l in open(path):
            if l.strip():
                r = json.loads(l)
                if "candidates" in r:
                    old[r["id"]] = r
        for r in sets.get(name, []):
            o = old.get(r["id"])
            if o is None:
                continue
            for s in SINGLE + ["union-b"]:
                if ok(r["candidates"][s]) != ok(o["candidates"][s]):
                    out.append(f"{name}:{r['id'].split('/')[-1]} {s}")
    return out


def main():
    args = [a for a in sys.argv[1:] if not a.startswith("EARLIER=")]
    earlier = dict(a[len("EARLIER="):].split("=", 1) for a in sys.argv[1:] if a.startswith("EARLIER="))
    sets = load_sets(args, end="\n\n")
    print("| set | pairs | " + " | ".join(SINGLE) + " | " + " | ".join(RULES) + " |")
    print("|---" * (2 + len(SINGLE) + len(RULES)) + "|")
    totals = {r: {"ok": 0, "lost": []} for r in RULES}
    for name, rows in sets.items():
        cells = [name, str(len(rows))]
        cells += [str(sum(ok(r["candidates"][s]) for r in rows)) for s in SINGLE]
        for rule in RULES:
            n_ok = 0
            for r in rows:
                good = rule_ok(rule, r)[0]
                n_ok += good
                if not good and any(ok(r["candidates"][s]) for s in SINGLE):
                    totals[rule]["lost"].append(f"{name}:{r['id'].split('/')[-1]}")
            cells.append(str(n_ok))
            totals[rule]["ok"] += n_ok
        print("| " + " | ".join(cells) + " |")
    n = sum(len(rows) for rows in sets.values())
    print()
    print(f"| rule | registered ({n}) | estimates per pair | pairs lost (a single branch registers it, the rule does not) |")
    print("|---|---|---|---|")
    for rule in RULES:
        t = totals[rule]
        print(f"| {rule} | {t['ok']} | {COST[rule]} | {len(t['lost'])} {' '.join(t['lost'])} |")
    print()
    chosen = sorted(RULES, key=lambda r: (len(totals[r]["lost"]), -totals[r]["ok"], COST[r], RULES.index(r)))[0]
    print(f"Decision rule (fewest lost, then most registered, then estimates, then order): **{chosen}**")
    print()
    if earlier:
        diff = compare_earlier(sets, earlier)
        print(f"Branch results that differ from the earlier rounds' lines: {len(diff)} {' '.join(diff)}")
        print()
    print("Pair by pair (ok / –; V of each pose; the pose each rule chose and what decided it):")
    print()
    print("| set | pair | split | geo | img | and | union | V geo | V and | V img | V union | " + " | ".join(RULES[1:]) + " |")
    print("|---" * (11 + len(RULES) - 1) + "|")
    m = lambda b: "ok" if b else "–"
    v = lambda c: str(c.get("vis", "err"))
    for name, rows in sets.items():
        for r in rows:
            c = r["candidates"]
            cells = [name, r["id"].split("/")[-1], r["split"]]
            cells += [m(ok(c[s])) for s in ["geometry", "image", "noisy-and", "union-b"]]
            cells += [v(c[s]) for s in ["geometry", "noisy-and", "image", "union-b"]]
            for rule in RULES[1:]:
                good, n, why = rule_ok(rule, r)
                cells.append(f"{m(good)} {n} ({why})")
            print("| " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
