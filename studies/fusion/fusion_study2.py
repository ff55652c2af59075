#!/usr/bin/env python3
"""The second round of the fusion study (docs/ablation.md, "The fusion study, second round"):
apply the candidate rules b, a3, a4, n3, n4 and the frozen decision rule to the lines
`cargo run --example fusion_study` wrote.

    python3 studies/fusion/fusion_study2.py D1=studies/fusion/results/dev/dev2-oracle.jsonl D2=studies/fusion/results/dev/dev2-clouds.jsonl
"""
import sys

# The first round's reader and success test (same JSON lines, same success criterion).
from fusion_study import SINGLE, load_sets, ok

RULES = ["b", "a3", "a4", "n3", "n4"]
COST = {"b": 1, "a3": 3, "a4": 4, "n3": 3, "n4": 4}
POSES = {
    "a3": ["geometry", "noisy-and", "image"],
    "a4": ["geometry", "union-b", "noisy-and", "image"],
    "n3": ["geometry", "noisy-and", "image"],
    "n4": ["geometry", "union-b", "noisy-and", "image"],
}


def balanced(row, c):
    """Σ over the branch sets of the share of the set within θ (each set one vote)."""
    return sum(c[f"fit_{k}"] / row[f"n_{k}"] for k in "gai" if row[f"n_{k}"] > 0)


def choose(rule, row):
    """(name of the chosen pose, what decided it)."""
    cands = row["candidates"]
    if rule == "b":
        return "union-b", "-"
    order = POSES[rule]
    live = [n for n in order if "error" not in cands[n]]
    if not live:
        return None, "none"
    if rule.startswith("a"):
        keys = [lambda n: cands[n]["fit3"], lambda n: -cands[n]["msac3"]]
    else:
        keys = [lambda n: balanced(row, cands[n]), lambda n: cands[n]["fit3"]]
    top = live
    for i, key in enumerate(keys):
        best = max(key(n) for n in top)
        top = [n for n in top if key(n) == best]
        if len(top) == 1:
            return top[0], ["score", "tie-break"][i]
    return top[0], "order"


def rule_ok(rule, row):
    n, why = choose(rule, row)
    return (ok(row["candidates"][n]) if n else False), n, why


def main():
    sets = load_sets(sys.argv[1:], end="\n\n")
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
    print()
    print("| rule | registered | estimates per pair | pairs lost (a single branch registers it, the rule does not) |")
    print("|---|---|---|---|")
    for rule in RULES:
        t = totals[rule]
        print(f"| {rule} | {t['ok']} | {COST[rule]} | {len(t['lost'])} {' '.join(t['lost'])} |")
    print()
    chosen = sorted(RULES, key=lambda r: (len(totals[r]["lost"]), -totals[r]["ok"], COST[r], RULES.index(r)))[0]
    print(f"Decision rule (fewest lost, then most registered, then estimates, then order): **{chosen}**")
    print()
    print("Pair by pair (ok / –; the pose each consensus rule chose and what decided it):")
    print()
    print("| set | pair | split | geo | img | and | union | " + " | ".join(RULES[1:]) + " |")
    print("|---" * (7 + len(RULES) - 1) + "|")
    m = lambda b: "ok" if b else "–"
    for name, rows in sets.items():
        for r in rows:
            c = r["candidates"]
            cells = [name, r["id"].split("/")[-1], r["split"]]
            cells += [m(ok(c[s])) for s in ["geometry", "image", "noisy-and", "union-b"]]
            for rule in RULES[1:]:
                good, n, why = rule_ok(rule, r)
                cells.append(f"{m(good)} {n} ({why})")
            print("| " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
