#!/usr/bin/env python3
"""The fusion study's rounds on development pairs (docs/ablation.md, appendix "The fusion rounds"), one
driver with a table of rounds. Each round names the development sets it reads (the lines `cargo run
--example fusion_study` writes, one JSON line per pair), its candidate rules, its frozen decision rule and
the report it wrote (results/dev/studyN.md); `run` also makes a round's fresh development pairs and lines.

    python3 studies/fusion/rounds.py list                 # the table of rounds
    python3 studies/fusion/rounds.py report N [--write]   # round N's report from the committed lines
    python3 studies/fusion/rounds.py report N NAME=PATH... # the same rules on other lines
    python3 studies/fusion/rounds.py run N CACHE_DIR      # make round N's lines, then its report

Every report is the one the round wrote when it was decided, byte for byte, from the committed lines
(`check` compares all of them). `run` appends a pair's line as it finishes and skips pairs already in a
file. The lines of rounds 1-3 came from earlier builds of the example: today's example no longer computes
the first round's candidate c, so round 1 reports only from its committed lines.
"""
import argparse
import json
import math
import os
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
DEV = "studies/fusion/results/dev"  # the lines and the reports, relative to the repository root
MANIFESTS = "assets/manifests"

SINGLE = ["geometry", "image", "noisy-and"]


def ok(c):
    return bool(c and "error" not in c and c["ok"])


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


# ---------------------------------------------------------------------------------------------------
# Round 1: pose consensus (a2, a3, a2-msac) against the union (b) and a neutral fusion (c).

R1_ORDER = ["geometry", "noisy-and", "image"]
R1_COST = {"a2": 2, "a3": 3, "a2-msac": 2, "b": 1, "c": 1}
R1_RULES = ["a2", "a3", "a2-msac", "b", "c"]


def r1_consensus(cands, names, k, msac_only=False):
    """(chosen name, decided by) under the pose-consensus rule on union k (2 or 3)."""
    live = [n for n in names if "error" not in cands[n]]
    if not live:
        return None, "none"
    if msac_only:
        best = min(cands[n][f"msac{k}"] for n in live)
        top = [n for n in live if cands[n][f"msac{k}"] == best]
        return sorted(top, key=R1_ORDER.index)[0], ("msac" if len(top) == 1 else "order")
    best = max(cands[n][f"fit{k}"] for n in live)
    top = [n for n in live if cands[n][f"fit{k}"] == best]
    if len(top) == 1:
        return top[0], "consensus"
    m = min(cands[n][f"msac{k}"] for n in top)
    low = [n for n in top if cands[n][f"msac{k}"] == m]
    if len(low) == 1:
        return low[0], "msac"
    return sorted(low, key=R1_ORDER.index)[0], "order"


def r1_rule_ok(rule, cands):
    if rule == "a2":
        n, why = r1_consensus(cands, ["geometry", "noisy-and"], 2)
    elif rule == "a3":
        n, why = r1_consensus(cands, ["geometry", "noisy-and", "image"], 3)
    elif rule == "a2-msac":
        n, why = r1_consensus(cands, ["geometry", "noisy-and"], 2, msac_only=True)
    elif rule == "b":
        return ok(cands.get("union-b")), "union-b", "-"
    else:
        return ok(cands.get("neutral-c")), "neutral-c", "-"
    return (ok(cands[n]) if n else False), n, why


def report_round1(args):
    sets = load_sets(args.sets)
    RULES = R1_RULES
    print("| set | pairs | " + " | ".join(SINGLE) + " | " + " | ".join(RULES) + " |")
    print("|---" * (2 + len(SINGLE) + len(RULES)) + "|")
    totals = {r: {"ok": 0, "lost": 0} for r in RULES}
    for name, rows in sets.items():
        cells = [name, str(len(rows))]
        for s in SINGLE:
            cells.append(str(sum(ok(r["candidates"][s]) for r in rows)))
        for rule in RULES:
            n_ok = sum(r1_rule_ok(rule, r["candidates"])[0] for r in rows)
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
                good, chosen, why = r1_rule_ok(rule, c)
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
    chosen = sorted(RULES, key=lambda r: (totals[r]["lost"], -totals[r]["ok"], R1_COST[r], RULES.index(r)))[0]
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
            a2 = r1_rule_ok("a2", c)
            cells = [name, r["id"].split("/")[-1], r["split"], m(ok(c["geometry"])), m(ok(c["image"])),
                     m(ok(c["noisy-and"])), m(a2[0]), m(r1_rule_ok("a3", c)[0]), m(r1_rule_ok("b", c)[0]),
                     m(r1_rule_ok("c", c)[0]), f"{a2[1]} ({a2[2]})",
                     f"{c['geometry'].get('fit2', '-')}/{c['noisy-and'].get('fit2', '-')}",
                     f"{c['geometry'].get('msac2', 0):.1f}/{c['noisy-and'].get('msac2', 0):.1f}"]
            print("| " + " | ".join(cells) + " |")


# ---------------------------------------------------------------------------------------------------
# Rounds 2 and 3: the union (b) against consensus (a3, a4) and balanced-share (n3, n4) arbiters.

R2_RULES = ["b", "a3", "a4", "n3", "n4"]
R2_COST = {"b": 1, "a3": 3, "a4": 4, "n3": 3, "n4": 4}
R2_POSES = {
    "a3": ["geometry", "noisy-and", "image"],
    "a4": ["geometry", "union-b", "noisy-and", "image"],
    "n3": ["geometry", "noisy-and", "image"],
    "n4": ["geometry", "union-b", "noisy-and", "image"],
}


def r2_balanced(row, c):
    """Σ over the branch sets of the share of the set within θ (each set one vote)."""
    return sum(c[f"fit_{k}"] / row[f"n_{k}"] for k in "gai" if row[f"n_{k}"] > 0)


def r2_choose(rule, row):
    """(name of the chosen pose, what decided it)."""
    cands = row["candidates"]
    if rule == "b":
        return "union-b", "-"
    order = R2_POSES[rule]
    live = [n for n in order if "error" not in cands[n]]
    if not live:
        return None, "none"
    if rule.startswith("a"):
        keys = [lambda n: cands[n]["fit3"], lambda n: -cands[n]["msac3"]]
    else:
        keys = [lambda n: r2_balanced(row, cands[n]), lambda n: cands[n]["fit3"]]
    top = live
    for i, key in enumerate(keys):
        best = max(key(n) for n in top)
        top = [n for n in top if key(n) == best]
        if len(top) == 1:
            return top[0], ["score", "tie-break"][i]
    return top[0], "order"


def r2_rule_ok(rule, row):
    n, why = r2_choose(rule, row)
    return (ok(row["candidates"][n]) if n else False), n, why


def report_round2(args):
    sets = load_sets(args.sets, end="\n\n")
    RULES = R2_RULES
    print("| set | pairs | " + " | ".join(SINGLE) + " | " + " | ".join(RULES) + " |")
    print("|---" * (2 + len(SINGLE) + len(RULES)) + "|")
    totals = {r: {"ok": 0, "lost": []} for r in RULES}
    for name, rows in sets.items():
        cells = [name, str(len(rows))]
        cells += [str(sum(ok(r["candidates"][s]) for r in rows)) for s in SINGLE]
        for rule in RULES:
            n_ok = 0
            for r in rows:
                good = r2_rule_ok(rule, r)[0]
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
        print(f"| {rule} | {t['ok']} | {R2_COST[rule]} | {len(t['lost'])} {' '.join(t['lost'])} |")
    print()
    chosen = sorted(RULES, key=lambda r: (len(totals[r]["lost"]), -totals[r]["ok"], R2_COST[r], RULES.index(r)))[0]
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
                good, n, why = r2_rule_ok(rule, r)
                cells.append(f"{m(good)} {n} ({why})")
            print("| " + " | ".join(cells) + " |")


# ---------------------------------------------------------------------------------------------------
# Round 4: free-space (visibility) consistency V as the arbiter (v2, v3, v4) against the union (b).

R4_RULES = ["b", "v2", "v3", "v4"]
R4_COST = {"b": 1, "v2": 2, "v3": 3, "v4": 4}
R4_POSES = {
    "b": ["union-b"],
    "v2": ["union-b", "noisy-and"],
    "v3": ["union-b", "geometry", "noisy-and"],
    "v4": ["union-b", "geometry", "noisy-and", "image"],
}


def r4_choose(rule, row):
    """(name of the chosen pose, what decided it): the largest V, ties by the order."""
    cands = row["candidates"]
    live = [n for n in R4_POSES[rule] if "error" not in cands[n]]
    if not live:
        return None, "none"
    if len(live) == 1:
        return live[0], "-"
    best = max(cands[n]["vis"] for n in live)
    top = [n for n in live if cands[n]["vis"] == best]
    return top[0], ("V" if len(top) == 1 else "order")


def r4_rule_ok(rule, row):
    n, why = r4_choose(rule, row)
    return (ok(row["candidates"][n]) if n else False), n, why


def r4_compare_earlier(sets, earlier):
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


def report_round4(args):
    sets = load_sets(args.sets, end="\n\n")
    earlier = dict(e.split("=", 1) for e in args.earlier)
    RULES = R4_RULES
    print("| set | pairs | " + " | ".join(SINGLE) + " | " + " | ".join(RULES) + " |")
    print("|---" * (2 + len(SINGLE) + len(RULES)) + "|")
    totals = {r: {"ok": 0, "lost": []} for r in RULES}
    for name, rows in sets.items():
        cells = [name, str(len(rows))]
        cells += [str(sum(ok(r["candidates"][s]) for r in rows)) for s in SINGLE]
        for rule in RULES:
            n_ok = 0
            for r in rows:
                good = r4_rule_ok(rule, r)[0]
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
        print(f"| {rule} | {t['ok']} | {R4_COST[rule]} | {len(t['lost'])} {' '.join(t['lost'])} |")
    print()
    chosen = sorted(RULES, key=lambda r: (len(totals[r]["lost"]), -totals[r]["ok"], R4_COST[r], RULES.index(r)))[0]
    print(f"Decision rule (fewest lost, then most registered, then estimates, then order): **{chosen}**")
    print()
    if earlier:
        diff = r4_compare_earlier(sets, earlier)
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
                good, n, why = r4_rule_ok(rule, r)
                cells.append(f"{m(good)} {n} ({why})")
            print("| " + " | ".join(cells) + " |")


# ---------------------------------------------------------------------------------------------------
# Rounds 5 and 6 arbitrate among candidate poses and guard the choice on the fresh pairs: one report.

def arbiter_tally(sets, virtual, names, rules, pick):
    """Per rule: registered and the lost pairs over the sets in `names`."""
    t = {r: {"ok": 0, "lost": []} for r in rules}
    for name in names:
        for row in sets[name]:
            single = any(ok(row["candidates"][s]) for s in SINGLE)
            for rule in rules:
                n, _ = pick(rule, row, name in virtual)
                good = ok(row["candidates"][n]) if n else False
                t[rule]["ok"] += good
                if single and not good:
                    t[rule]["lost"].append(f"{name}:{row['id'].split('/')[-1]}")
    return t


def arbiter_report(sets, virtual, fresh, rules, pick, scores):
    """Print the round's tables. `rules[0]` is the present default (the baseline of the guard);
    `scores` is [(column title, function of a candidate)] shown per pose on the fresh pairs."""
    base = rules[0]
    print("| set | views | pairs | " + " | ".join(SINGLE) + " | " + " | ".join(rules) + " |")
    print("|---" * (3 + len(SINGLE) + len(rules)) + "|")
    for name, rows in sets.items():
        cells = [name, "virtual" if name in virtual else "sensor", str(len(rows))]
        cells += [str(sum(ok(r["candidates"][s]) for r in rows)) for s in SINGLE]
        t = arbiter_tally(sets, virtual, [name], rules, pick)
        cells += [str(t[r]["ok"]) for r in rules]
        print("| " + " | ".join(cells) + " |")
    everything = arbiter_tally(sets, virtual, list(sets), rules, pick)
    new = arbiter_tally(sets, virtual, [s for s in fresh if s in sets], rules, pick)
    n_all = sum(len(r) for r in sets.values())
    n_new = sum(len(sets[s]) for s in fresh if s in sets)
    print()
    print(f"| rule | registered, all ({n_all}) | lost, all | registered, fresh ({n_new}) | lost, fresh |")
    print("|---|---|---|---|---|")
    for rule in rules:
        e, f = everything[rule], new[rule]
        print(f"| {rule} | {e['ok']} | {len(e['lost'])} {' '.join(e['lost'])} | {f['ok']} | "
              f"{len(f['lost'])} {' '.join(f['lost'])} |")
    print()
    ranked = sorted(rules, key=lambda r: (len(everything[r]["lost"]), -everything[r]["ok"], rules.index(r)))
    first = ranked[0]
    guard = first == base or (len(new[first]["lost"]) <= len(new[base]["lost"]) and new[first]["ok"] >= new[base]["ok"])
    chosen = first if guard else base
    print(f"Decision rule (fewest lost, then most registered, then order) over all pairs: **{first}**; "
          f"on the fresh pairs it {'meets' if guard else 'fails'} the guard (no more lost, no fewer "
          f"registered than {base}): **{chosen}**")
    print()
    print("Fresh pairs, pair by pair (ok / –; " + ", ".join(t for t, _ in scores)
          + " of each pose; the pose each rule chose):")
    print()
    poses = [("geo", "geometry"), ("and", "noisy-and"), ("img", "image"), ("union", "union-b")]
    head = ["set", "pair", "split", "geo", "img", "and", "union"]
    head += [f"{t} {p}" for t, _ in scores for p, _ in poses] + rules
    print("| " + " | ".join(head) + " |")
    print("|---" * len(head) + "|")
    m = lambda b: "ok" if b else "–"
    for name in fresh:
        for r in sets.get(name, []):
            c = r["candidates"]
            cells = [name, r["id"].split("/")[-1], r["split"]]
            cells += [m(ok(c[s])) for s in ["geometry", "image", "noisy-and", "union-b"]]
            cells += [("err" if "error" in c[s] else f(c[s])) for _, f in scores for _, s in poses]
            for rule in rules:
                n, why = pick(rule, r, name in virtual)
                cells.append(f"{m(ok(c[n]) if n else False)} {n} ({why})")
            print("| " + " | ".join(cells) + " |")


def arbiter_args(args):
    virtual = set(filter(None, args.virtual.split(",")))
    fresh = [s for s in args.fresh.split(",") if s]
    return load_sets(args.sets, end="\n\n"), virtual, fresh


# Round 5: visibility arbitration only where the views look out from the sensor (v3s, v4s).

R5_RULES = ["v3", "v3s", "v4s"]
R5_POSES = {
    "v3": ["union-b", "geometry", "noisy-and"],
    "v4": ["union-b", "geometry", "noisy-and", "image"],
}


def r5_pick(rule, row, virtual):
    """(chosen pose, what decided it) for one row."""
    if rule in ("v3s", "v4s") and virtual:
        return "union-b", "virtual views"
    base = "v4" if rule == "v4s" else "v3"
    cands = row["candidates"]
    live = [n for n in R5_POSES[base] if "error" not in cands[n]]
    if not live:
        return None, "none"
    best = max(cands[n]["vis"] for n in live)
    top = [n for n in live if cands[n]["vis"] == best]
    return top[0], ("V" if len(top) == 1 else "order")


def report_round5(args):
    arbiter_report(*arbiter_args(args), R5_RULES, r5_pick, [("V", lambda c: str(c["vis"]))])


# Round 6: the share of seen keypoints that agree (a Wilson lower bound, F), not their count (f3s, f4s, f4).

R6_RULES = ["v3s", "f3s", "f4s", "f4"]
R6_THREE = ["union-b", "geometry", "noisy-and"]
R6_Z = 1.96


def r6_share(c):
    """F: the Wilson lower bound (z = 1.96) of consistent / (consistent + conflicting), both
    directions summed; 0 when no keypoint is seen."""
    Z = R6_Z
    good = c["vis_st"][0] + c["vis_ts"][0]
    n = good + c["vis_st"][1] + c["vis_ts"][1]
    if n == 0:
        return 0.0
    p = good / n
    return (p + Z * Z / (2 * n) - Z * math.sqrt(p * (1 - p) / n + Z * Z / (4 * n * n))) / (1 + Z * Z / n)


def r6_pick(rule, row, virtual):
    """(chosen pose, what decided it) for one row."""
    if rule != "f4" and virtual:
        return "union-b", "virtual views"
    names = R6_THREE + (["image"] if rule in ("f4s", "f4") else [])
    score = (lambda c: c["vis"]) if rule == "v3s" else r6_share
    cands = row["candidates"]
    live = [n for n in names if "error" not in cands[n]]
    if not live:
        return None, "none"
    best = max(score(cands[n]) for n in live)
    top = [n for n in live if score(cands[n]) == best]
    return top[0], (("V" if rule == "v3s" else "F") if len(top) == 1 else "order")


def report_round6(args):
    arbiter_report(*arbiter_args(args), R6_RULES, r6_pick,
                   [("V", lambda c: str(c["vis"])), ("F", lambda c: f"{r6_share(c):.4f}")])


# ---------------------------------------------------------------------------------------------------
# The table of rounds. `sets`: NAME -> the lines file under DEV; `earlier`: NAME -> an earlier round's
# lines of the same pairs (round 4 lists the pairs whose single-branch results changed); `fresh`: the
# sets nobody had looked at when the round's rules were designed; `virtual`: sets whose depth views are
# a virtual pinhole trajectory (clouds only, built-in frames). `make`: the manifest a round writes
# (fresh 3DLoMatch-like pairs of fragments starting at 50k+OFFSET) and the study example's runs, in
# order: (set, manifest, frames, --split or None); a set "NNc" runs --clouds-only.

def _vis(*names):
    return {n: f"vis-{n}.jsonl" for n in names}


D1 = f"{MANIFESTS}/redkitchen-dev.toml"
ROUNDS = {
    1: dict(title="pose consensus on the union of two or three branches' sets: chose b, the union",
            report=report_round1, out="study.md",
            sets={"D1": "dev-oracle.jsonl", "D2": "dev-clouds.jsonl"},
            make=(None, [("D1", D1, "oracle", "3DLoMatch-like"), ("D2", D1, "builtin", "3DLoMatch-like")]),
            files={"D1": "dev-oracle.jsonl", "D2": "dev-clouds.jsonl"}),
    2: dict(title="consensus and balanced-share arbiters on all 60 development pairs: b stays",
            report=report_round2, out="study2.md",
            sets={"D1": "dev2-oracle.jsonl", "D2": "dev2-clouds.jsonl"},
            make=(None, [(s, D1, w, sp) for sp in ("3DLoMatch-like", "3DMatch-like")
                         for s, w in (("D1", "oracle"), ("D2", "builtin"))]),
            files={"D1": "dev2-oracle.jsonl", "D2": "dev2-clouds.jsonl"}),
    3: dict(title="the second round's rules on new low-overlap pairs (D3): b stays, and fails there",
            report=report_round2, out="study3.md",
            sets={"D1": "dev2-oracle.jsonl", "D2": "dev2-clouds.jsonl",
                  "D3": "dev3-oracle.jsonl", "D3c": "dev3-clouds.jsonl"},
            make=((3, "12 37"), [("D3", f"{MANIFESTS}/redkitchen-dev3.toml", "oracle", None),
                                 ("D3c", f"{MANIFESTS}/redkitchen-dev3.toml", "builtin", None)]),
            files={"D3": "dev3-oracle.jsonl", "D3c": "dev3-clouds.jsonl"}),
    4: dict(title="free-space consistency V as the arbiter: chose v3, the visibility fusion",
            report=report_round4, out="study4.md",
            sets=_vis("D4", "D4c", "D3", "D3c", "D1", "D2"),
            earlier={"D3": "dev3-oracle.jsonl", "D3c": "dev3-clouds.jsonl",
                     "D1": "dev2-oracle.jsonl", "D2": "dev2-clouds.jsonl"},
            make=((4, "6 31"), [("D4", f"{MANIFESTS}/redkitchen-dev4.toml", "oracle", None),
                                ("D4c", f"{MANIFESTS}/redkitchen-dev4.toml", "builtin", None),
                                ("D3", f"{MANIFESTS}/redkitchen-dev3.toml", "oracle", None),
                                ("D3c", f"{MANIFESTS}/redkitchen-dev3.toml", "builtin", None)]
                  + [(s, D1, w, sp) for sp in ("3DLoMatch-like", "3DMatch-like")
                     for s, w in (("D1", "oracle"), ("D2", "builtin"))]),
            files=_vis("D4", "D4c", "D3", "D3c", "D1", "D2")),
    5: dict(title="visibility only where the views look out from the sensor: chose v3s",
            report=report_round5, out="study5.md",
            sets=_vis("D5", "D5c", "D1", "D2", "D3", "D3c", "D4", "D4c"),
            virtual="D2,D3c,D4c,D5c", fresh="D5,D5c",
            make=((5, "18 43"), [("D5", f"{MANIFESTS}/redkitchen-dev5.toml", "oracle", None),
                                 ("D5c", f"{MANIFESTS}/redkitchen-dev5.toml", "builtin", None)]),
            files=_vis("D5", "D5c")),
    6: dict(title="the share of seen keypoints that agree, not their count: chose f4",
            report=report_round6, out="study6.md",
            sets=_vis("D6", "D6c", "D1", "D2", "D3", "D3c", "D4", "D4c", "D5", "D5c"),
            virtual="D2,D3c,D4c,D5c,D6c", fresh="D6,D6c",
            make=((6, "15 34 47"), [("D6", f"{MANIFESTS}/redkitchen-dev6.toml", "oracle", None),
                                    ("D6c", f"{MANIFESTS}/redkitchen-dev6.toml", "builtin", None)]),
            files=_vis("D6", "D6c")),
}


def round_args(n, given):
    """The report's inputs: the round's own sets from the table, or NAME=PATH arguments given."""
    r = ROUNDS[n]
    sets = given or [f"{k}={os.path.join(DEV, v)}" for k, v in r["sets"].items()]
    earlier = [] if given else [f"{k}={os.path.join(DEV, v)}" for k, v in r.get("earlier", {}).items()]
    return argparse.Namespace(sets=sets, earlier=earlier, virtual=r.get("virtual", ""),
                              fresh=r.get("fresh", ""))


def render(n, given=None):
    """Round n's report as text."""
    import contextlib
    import io
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        ROUNDS[n]["report"](round_args(n, given))
    return buf.getvalue()


def make_lines(n, cache):
    """Round n's fresh manifest (unless it exists) and the study example's lines of its sets."""
    r = ROUNDS[n]
    fresh, runs = r["make"]
    if fresh:
        k, offsets = fresh
        manifest = f"{MANIFESTS}/redkitchen-dev{k}.toml"
        if not os.path.exists(manifest):
            env = dict(os.environ, OFFSETS=offsets, DEV_NAME=f"redkitchen-dev{k}", DEV_MANIFEST=manifest,
                       LOMATCH_ONLY="1")
            subprocess.run(["bash", "studies/dev-sweep/devset_candidates.sh", f"target/devset{k}", cache],
                           env=env, check=True)
    exe = os.environ.get("CGENREG_EXAMPLE_BIN", "target/debug/examples/fusion_study")
    for name, manifest, wfm, split in runs:
        cmd = ["nice", "-n", "5", exe, manifest, "--wfm", wfm, "--cache-dir", cache,
               "--out", os.path.join(DEV, r["files"][name])]
        if wfm == "builtin":
            cmd.append("--clouds-only")
        if split:
            cmd += ["--split", split]
        subprocess.run(cmd, check=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    sub.add_parser("list", help="the table of rounds")
    rep = sub.add_parser("report", help="a round's report (stdout; --write: its file under results/dev)")
    rep.add_argument("round", type=int, choices=sorted(ROUNDS))
    rep.add_argument("--write", action="store_true")
    rep.add_argument("sets", nargs="*", help="NAME=PATH lines to read instead of the round's own")
    run = sub.add_parser("run", help="make a round's lines with the study example, then write its report")
    run.add_argument("round", type=int, choices=sorted(ROUNDS))
    run.add_argument("cache", help="the stage cache folder")
    sub.add_parser("check", help="the rounds' reports from the committed lines equal their files")
    a = ap.parse_args()
    if getattr(a, "sets", None):  # paths given relative to where the command runs
        a.sets = [f"{k}={os.path.abspath(v)}" for k, v in (x.split("=", 1) for x in a.sets)]
    os.chdir(ROOT)
    if a.cmd == "list":
        print("| round | question and choice | sets read | report |")
        print("|---|---|---|---|")
        for n, r in ROUNDS.items():
            print(f"| {n} | {r['title']} | {', '.join(r['sets'])} | {DEV}/{r['out']} |")
    elif a.cmd == "check":
        bad = [n for n in ROUNDS if render(n) != open(os.path.join(DEV, ROUNDS[n]["out"])).read()]
        for n in ROUNDS:
            print(f"round {n}: {'differs' if n in bad else 'equal'} ({DEV}/{ROUNDS[n]['out']})")
        sys.exit(1 if bad else 0)
    else:
        if a.cmd == "run":
            make_lines(a.round, a.cache)
        text = render(a.round, getattr(a, "sets", None))
        if a.cmd == "run" or a.write:
            with open(os.path.join(DEV, ROUNDS[a.round]["out"]), "w") as f:
                f.write(text)
        print(text, end="")


if __name__ == "__main__":
    main()
