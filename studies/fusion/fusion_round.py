"""The report of one round of the fusion study that arbitrates among candidate poses (the fifth round
on): per set, the pairs each rule registers; over all development pairs and over the fresh ones, the
pairs each rule registers and loses; the frozen decision rule with its guard on the fresh pairs; the
fresh pairs pair by pair. A round gives its rules, its baseline and how a rule picks a pose.
"""
import argparse

from fusion_study import SINGLE, load_sets, ok


def parse_args(doc):
    ap = argparse.ArgumentParser(description=doc, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--virtual", default="", help="sets whose views are a virtual trajectory")
    ap.add_argument("--fresh", default="", help="sets nobody had looked at when the rules were designed")
    ap.add_argument("sets", nargs="+", help="NAME=PATH of a study's lines")
    a = ap.parse_args()
    virtual = set(filter(None, a.virtual.split(",")))
    fresh = [s for s in a.fresh.split(",") if s]
    return load_sets(a.sets, end="\n\n"), virtual, fresh


def tally(sets, virtual, names, rules, pick):
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


def report(sets, virtual, fresh, rules, pick, scores):
    """Print the round's tables. `rules[0]` is the present default (the baseline of the guard);
    `scores` is [(column title, function of a candidate)] shown per pose on the fresh pairs."""
    base = rules[0]
    print("| set | views | pairs | " + " | ".join(SINGLE) + " | " + " | ".join(rules) + " |")
    print("|---" * (3 + len(SINGLE) + len(rules)) + "|")
    for name, rows in sets.items():
        cells = [name, "virtual" if name in virtual else "sensor", str(len(rows))]
        cells += [str(sum(ok(r["candidates"][s]) for r in rows)) for s in SINGLE]
        t = tally(sets, virtual, [name], rules, pick)
        cells += [str(t[r]["ok"]) for r in rules]
        print("| " + " | ".join(cells) + " |")
    everything = tally(sets, virtual, list(sets), rules, pick)
    new = tally(sets, virtual, [s for s in fresh if s in sets], rules, pick)
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
