#!/usr/bin/env python3
"""The fifth round of the fusion study (docs/ablation.md, "The fusion study, fifth round"): apply the
candidate rules v3, v3s, v4s (visibility arbitration only with sensor views) and the frozen decision
rule to the lines `cargo run --example fusion_study` wrote.

    python3 scripts/fusion_study5.py --virtual D2,D3c,D4c,D5c --fresh D5,D5c D5=PATH D5c=PATH D1=PATH ...

--virtual names the sets whose depth views are a virtual pinhole trajectory (clouds only, built-in
frames); every other set has sensor views. --fresh names the development sets nobody had looked at when
the candidates were designed.
"""
import argparse

from fusion_study import SINGLE, load_sets, ok

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


def tally(sets, virtual_sets, names):
    """Per rule: registered and the lost pairs over the sets in `names`."""
    t = {r: {"ok": 0, "lost": []} for r in RULES}
    for name in names:
        for row in sets[name]:
            single = any(ok(row["candidates"][s]) for s in SINGLE)
            for rule in RULES:
                n, _ = pick(rule, row, name in virtual_sets)
                good = ok(row["candidates"][n]) if n else False
                t[rule]["ok"] += good
                if single and not good:
                    t[rule]["lost"].append(f"{name}:{row['id'].split('/')[-1]}")
    return t


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--virtual", default="")
    ap.add_argument("--fresh", default="")
    ap.add_argument("sets", nargs="+")
    a = ap.parse_args()
    virtual = set(filter(None, a.virtual.split(",")))
    fresh = [s for s in a.fresh.split(",") if s]
    sets = load_sets(a.sets, end="\n\n")
    print("| set | views | pairs | " + " | ".join(SINGLE) + " | " + " | ".join(RULES) + " |")
    print("|---" * (3 + len(SINGLE) + len(RULES)) + "|")
    for name, rows in sets.items():
        cells = [name, "virtual" if name in virtual else "sensor", str(len(rows))]
        cells += [str(sum(ok(r["candidates"][s]) for r in rows)) for s in SINGLE]
        t = tally(sets, virtual, [name])
        cells += [str(t[r]["ok"]) for r in RULES]
        print("| " + " | ".join(cells) + " |")
    everything = tally(sets, virtual, list(sets))
    new = tally(sets, virtual, [s for s in fresh if s in sets])
    n_all = sum(len(r) for r in sets.values())
    n_new = sum(len(sets[s]) for s in fresh if s in sets)
    print()
    print(f"| rule | registered, all ({n_all}) | lost, all | registered, fresh ({n_new}) | lost, fresh |")
    print("|---|---|---|---|---|")
    for rule in RULES:
        e, f = everything[rule], new[rule]
        print(f"| {rule} | {e['ok']} | {len(e['lost'])} {' '.join(e['lost'])} | {f['ok']} | "
              f"{len(f['lost'])} {' '.join(f['lost'])} |")
    print()
    ranked = sorted(RULES, key=lambda r: (len(everything[r]["lost"]), -everything[r]["ok"], RULES.index(r)))
    first = ranked[0]
    guard = first == "v3" or (len(new[first]["lost"]) <= len(new["v3"]["lost"]) and new[first]["ok"] >= new["v3"]["ok"])
    chosen = first if guard else "v3"
    print(f"Decision rule (fewest lost, then most registered, then order) over all pairs: **{first}**; "
          f"on the fresh pairs it {'meets' if guard else 'fails'} the guard (no more lost, no fewer "
          f"registered than v3): **{chosen}**")
    print()
    print("Fresh pairs, pair by pair (ok / –; V of each pose; the pose each rule chose):")
    print()
    print("| set | pair | split | geo | img | and | union | V geo | V and | V img | V union | " + " | ".join(RULES) + " |")
    print("|---" * (11 + len(RULES)) + "|")
    m = lambda b: "ok" if b else "–"
    v = lambda c: str(c.get("vis", "err"))
    for name in fresh:
        for r in sets.get(name, []):
            c = r["candidates"]
            cells = [name, r["id"].split("/")[-1], r["split"]]
            cells += [m(ok(c[s])) for s in ["geometry", "image", "noisy-and", "union-b"]]
            cells += [v(c[s]) for s in ["geometry", "noisy-and", "image", "union-b"]]
            for rule in RULES:
                n, why = pick(rule, r, name in virtual)
                cells.append(f"{m(ok(c[n]) if n else False)} {n} ({why})")
            print("| " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
