#!/usr/bin/env python3
"""The ICP probe on development pairs (docs/ablation.md, "A probe after the fifth round"): the
`visibility` fusion's kept pose (v3s: the largest V of union, geometry, Noisy-AND with sensor
views; the union's pose with virtual views) before and after point-to-plane ICP on the keypoint
clouds, at the inlier threshold θ (`icp1_*`) and coarse to fine at 4θ, 2θ, θ (`icp3_*`), from the
lines `cargo run --example fusion_study` writes.

    python3 studies/fusion/fusion_icp_probe.py --virtual D4c,D5c D4=PATH D4c=PATH D5=PATH D5c=PATH
"""
import argparse
import json

SINGLE = ["geometry", "image", "noisy-and"]
V3 = ["union-b", "geometry", "noisy-and"]


def kept(c, virtual):
    if virtual:
        return "union-b"
    live = [n for n in V3 if "error" not in c[n]]
    return max(live, key=lambda n: (c[n]["vis"], -V3.index(n)))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--virtual", default="")
    ap.add_argument("sets", nargs="+")
    a = ap.parse_args()
    virtual = set(filter(None, a.virtual.split(",")))
    print("| set | views | pairs | a single branch | kept pose | after ICP at θ | after ICP 4θ, 2θ, θ "
          "| lost (kept) | lost (ICP at θ) |")
    print("|---" * 9 + "|")
    changes = []
    for arg in a.sets:
        name, path = arg.split("=", 1)
        rows = [json.loads(l) for l in open(path) if l.strip()]
        n = {"single": 0, "ok": 0, "icp1": 0, "icp3": 0, "lost": 0, "lost1": 0}
        for r in rows:
            c = r["candidates"]
            x = c[kept(c, name in virtual)]
            single = any(c[s].get("ok") for s in SINGLE)
            n["single"] += single
            n["ok"] += x["ok"]
            n["icp1"] += x["icp1_ok"]
            n["icp3"] += x["icp3_ok"]
            n["lost"] += single and not x["ok"]
            n["lost1"] += single and not x["icp1_ok"]
            if x["ok"] != x["icp1_ok"]:
                changes.append(f"{name} {r['id'].split('/')[-1]}: {x['rre']:.1f}° / {x['rte']:.2f} m -> "
                               f"{x['icp1_rre']:.1f}° / {x['icp1_rte']:.2f} m "
                               f"({'registered' if x['icp1_ok'] else 'lost'} after ICP at θ)")
        print(f"| {name} | {'virtual' if name in virtual else 'sensor'} | {len(rows)} | {n['single']} | "
              f"{n['ok']} | {n['icp1']} | {n['icp3']} | {n['lost']} | {n['lost1']} |")
    print()
    for c in changes:
        print(f"- {c}")


if __name__ == "__main__":
    main()
