#!/usr/bin/env python3
"""Apply the fusion rules of the protocol (docs/ablation.md, "A fusion that never loses to its
best branch") to the lines `cargo run --example fusion_study` wrote, and the frozen decision rule.

    python3 studies/fusion/fusion_study.py D1=studies/fusion/results/dev/dev-oracle.jsonl D2=studies/fusion/results/dev/dev-clouds.jsonl

Prints, per rule: pairs registered per set, pairs lost against geometry alone / image alone /
Noisy-AND, ties and how they were decided, then the rule the decision rule chooses.
"""
import json
import sys

SINGLE = ["geometry", "image", "noisy-and"]
ORDER = ["geometry", "noisy-and", "image"]
COST = {"a2": 2, "a3": 3, "a2-msac": 2, "b": 1, "c": 1}
RULES = ["a2", "a3", "a2-msac", "b", "c"]


def ok(c):
    return bool(c and "error" not in c and c["ok"])


def consensus(cands, names, k, msac_only=False):
    """(chosen name, decided by) under the pose-consensus rule on union k (2 or 3)."""
    live = [n for n in names if "error" not in cands[n]]
    if not live:
        return None, "none"
    if msac_only:
        best = min(cands[n][f"msac{k}"] for n in live)
        top = [n for n in live if cands[n][f"msac{k}"] == best]
        return sorted(top, key=ORDER.index)[0], ("msac" if len(top) == 1 else "order")
    best = max(cands[n][f"fit{k}"] for n in live)
    top = [n for n in live if cands[n][f"fit{k}"] == best]
    if len(top) == 1:
        return top[0], "consensus"
    m = min(cands[n][f"msac{k}"] for n in top)
    low = [n for n in top if cands[n][f"msac{k}"] == m]
    if len(low) == 1:
        return low[0], "msac"
    return sorted(low, key=ORDER.index)[0], "order"


def rule_ok(rule, cands):
    if rule == "a2":
        n, why = consensus(cands, ["geometry", "noisy-and"], 2)
    elif rule == "a3":
        n, why = consensus(cands, ["geometry", "noisy-and", "image"], 3)
    elif rule == "a2-msac":
        n, why = consensus(cands, ["geometry", "noisy-and"], 2, msac_only=True)
    elif rule == "b":
        return ok(cands.get("union-b")), "union-b", "-"
    else:
        return ok(cands.get("neutral-c")), "neutral-c", "-"
    return (ok(cands[n]) if n else False), n, why


def load_sets(args, end="\n"):
    """{set name: rows with candidates} from NAME=PATH arguments; pairs that failed to run are
    named on stdout."""
    sets = {}
    for arg in args:
        name, path = arg.split("=", 1)
        rows = [json.loads(l) for l in open(path) if l.strip()]
        sets[name] = [r for r in rows if "candidates" in r]
        bad = [r["id"] for r in rows if "candidates" not in r]
        if bad:
            print(f"{name}: {len(bad)} pairs failed to run: {', '.join(bad)}", end=end)
    return sets


def main():
    sets = load_sets(sys.argv[1:])
    print("| set | pairs | " + " | ".join(SINGLE) + " | " + " | ".join(RULES) + " |")
    print("|---" * (2 + len(SINGLE) + len(RULES)) + "|")
    totals = {r: {"ok": 0, "lost": 0} for r in RULES}
    for name, rows in sets.items():
        cells = [name, str(len(rows))]
        for s in SINGLE:
            cells.append(str(sum(ok(r["candidates"][s]) for r in rows)))
        for rule in RULES:
            n_ok = sum(rule_ok(rule, r["candidates"])[0] for r in rows)
            cells.append(str(n_ok))
            totals[rule]["ok"] += n_ok
        print("| " + " | ".join(cells) + " |")
    print()
    print("Per rule: pairs lost (a single row registers it, the rule does not), ties")
    print()
    print("| rule | registered | lost | lost vs geometry | lost vs image | lost vs Noisy-AND | decided by MSAC | by order |")
    print("|---|---|---|---|---|---|---|---|")
    for rule in RULES:
        lost, lost_by, ties = [], {s: 0 for s in SINGLE}, {"msac": 0, "order": 0}
        for name, rows in sets.items():
            for r in rows:
                c = r["candidates"]
                good, chosen, why = rule_ok(rule, c)
                if why in ties:
                    ties[why] += 1
                singles = [s for s in SINGLE if ok(c[s])]
                if singles and not good:
                    lost.append(f"{name}:{r['id']}")
                for s in singles:
                    if not good:
                        lost_by[s] += 1
        totals[rule]["lost"] = len(lost)
        print(f"| {rule} | {totals[rule]['ok']} | {len(lost)} {' '.join(lost)} | "
              + " | ".join(str(lost_by[s]) for s in SINGLE)
              + f" | {ties['msac']} | {ties['order']} |")
    print()
    chosen = sorted(RULES, key=lambda r: (totals[r]["lost"], -totals[r]["ok"], COST[r], RULES.index(r)))[0]
    print(f"Decision rule (fewest lost, then most registered, then cost, then order): {chosen}")
    print()
    print("Pair by pair (ok/-: geometry, image, Noisy-AND | a2 choice, fit2 geometry vs Noisy-AND, MSAC2):")
    print()
    print("| set | pair | split | geo | img | and | a2 | a3 | b | c | a2 chose | fit2 g/a | msac2 g/a |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for name, rows in sets.items():
        for r in rows:
            c = r["candidates"]
            m = lambda b: "ok" if b else "–"
            a2 = rule_ok("a2", c)
            cells = [name, r["id"].split("/")[-1], r["split"], m(ok(c["geometry"])), m(ok(c["image"])),
                     m(ok(c["noisy-and"])), m(a2[0]), m(rule_ok("a3", c)[0]), m(rule_ok("b", c)[0]),
                     m(rule_ok("c", c)[0]), f"{a2[1]} ({a2[2]})",
                     f"{c['geometry'].get('fit2', '-')}/{c['noisy-and'].get('fit2', '-')}",
                     f"{c['geometry'].get('msac2', 0):.1f}/{c['noisy-and'].get('msac2', 0):.1f}"]
            print("| " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
