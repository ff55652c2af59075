#!/usr/bin/env python3
"""The revisit set's table (docs/ablation.md, "Revisits"), from the committed JSONs: per pair the GT
rotation, translation and overlap the manifest records, every mode's RRE / RTE (oracle RGB and
clouds only), and Open3D's successes over its seeds.

    python3 studies/revisit/revisit_table.py > studies/revisit/results/table.md

Reads assets/manifests/redkitchen-revisit.toml, studies/fusion/results/eval/revisit{,-clouds}-<mode>.json
(studies/fusion/fusion_eval.sh) and studies/revisit/results/open3d-seed*.json (studies/outdoor/open3d_outdoor.sh).
"""
import glob
import json
import os
import re

MANIFEST = "assets/manifests/redkitchen-revisit.toml"
FUSION = "studies/fusion/results/eval"
O3D = "studies/revisit/results"
MODES = [("geometry", "geometry alone"), ("image", "image alone"), ("noisy-and", "Noisy-AND"),
         ("union", "union"), ("visibility", "visibility (default)")]
GT = re.compile(r"# GT rotation ([\d.]+) deg, translation ([\d.]+) m, (\d+) frames apart, overlap ([\d.]+) %")


def manifest_pairs():
    """[(pair key 'T-S', rotation, translation, gap, overlap)] in manifest order."""
    out, gt = [], None
    for line in open(MANIFEST):
        m = GT.match(line.strip())
        if m:
            gt = m.groups()
        elif line.startswith("target") and gt:
            t = line.split('"')[1]
        elif line.startswith("source") and gt:
            out.append((f"{t}-{line.split(chr(34))[1]}",) + gt)
            gt = None
    return out


def runs(prefix):
    res = {}
    for mode, _ in MODES:
        path = os.path.join(FUSION, f"{prefix}-{mode}.json")
        if os.path.exists(path):
            d = json.load(open(path))
            res[mode] = {r["id"].split("/")[-1]: r for r in d["pairs"]}
    return res


def cell(r):
    if r is None or r.get("error"):
        return "not run" if r is None else "error"
    s = f"{r['rre_deg']:.1f} / {r['rte_m']:.2f}"
    return f"**{s}**" if r.get("success") else s


def main():
    pairs = manifest_pairs()
    oracle, clouds = runs("revisit"), runs("revisit-clouds")
    seeds = sorted(glob.glob(os.path.join(O3D, "open3d-seed*.json")))
    o3d = [json.load(open(p)) for p in seeds]
    o3d_ok = {}
    for d in o3d:
        for r in d["pairs"]:
            o3d_ok.setdefault(r["id"].split("/")[-1], []).append(r["success"][0])
    print("RRE ° / RTE m per pair; **bold**: a success (RRE ≤ 15°, RTE ≤ 30 cm). GT rotation and")
    print("translation of target_from_source, frames between the fragments' first frames, GT overlap.")
    print()
    for title, res, note in [("oracle RGB + ALIKE-t (sensor views)", oracle, ""),
                             ("clouds only: built-in frames + ALIKE-t (virtual views)", clouds, "")]:
        print(f"### {title}")
        print()
        print("| pair | GT rotation ° | GT translation m | frames apart | overlap % | "
              + " | ".join(l for _, l in MODES) + " |")
        print("|---" * (5 + len(MODES)) + "|")
        for key, rot, tr, gap, ov in pairs:
            print(f"| {key} | {rot} | {tr} | {gap} | {ov} | "
                  + " | ".join(cell(res.get(m, {}).get(key)) for m, _ in MODES) + " |")
        n = len(pairs)
        print("| registered | | | | | " + " | ".join(
            f"{sum(bool(res.get(m, {}).get(k, {}).get('success')) for k, *_ in pairs)}/{n}"
            for m, _ in MODES) + " |")
        print()
    if o3d:
        d0 = o3d[0]
        print(f"### Open3D {d0['open3d']} FPFH + RANSAC on the same PLY files")
        print()
        print(f"{d0['method']}, voxel {d0['voxel_m']} m, distance {d0['ransac_distance_m']:g} m, "
              f"seeds {', '.join(str(d['seed']) for d in o3d)}; success RRE ≤ "
              f"{d0['criteria'][0]['max_rre_deg']:g}°, RTE ≤ {d0['criteria'][0]['max_rte_m']:g} m.")
        print()
        print("| pair | seeds registered | RRE ° / RTE m per seed | s per pair (mean) |")
        print("|---|---|---|---|")
        for key, *_ in pairs:
            per = [next((r for r in d["pairs"] if r["id"].endswith("/" + key)), None) for d in o3d]
            ok = sum(bool(r and r["success"][0]) for r in per)
            cells = ", ".join(f"{r['rre_deg']:.1f} / {r['rte_m']:.2f}" if r else "not run" for r in per)
            t = [r["time_s"] for r in per if r]
            print(f"| {key} | {ok}/{len(o3d)} | {cells} | {sum(t) / max(len(t), 1):.1f} |")
        print("| pairs registered in at least one seed | "
              f"{sum(any(v) for v in o3d_ok.values())}/{len(pairs)} | | |")
        print()
    print("From: `bash studies/revisit/revisit_set.sh CACHE`, then `bash studies/fusion/fusion_eval.sh revisit` and "
          "`bash studies/fusion/fusion_eval.sh revisit-clouds` (the run parameters are in each JSON's `run`), "
          "then `bash studies/outdoor/open3d_outdoor.sh --voxel 0.025 --seed S --success 15:0.3 --json "
          "studies/revisit/results/open3d-seedS.json target/revisit/clouds.toml` for S = 0..4.")


if __name__ == "__main__":
    main()
