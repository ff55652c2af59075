#!/usr/bin/env python3
"""Pick the revisit pairs (docs/ablation.md, "Revisits: the hardest loop closures the sequence
holds") from the overlap table `examples/pair_overlap.rs` printed for the candidate manifest, and
write the evaluated manifest.

    python3 studies/revisit/revisit_select.py CANDIDATES.toml OVERLAP.tsv OUT.toml

The rule, fixed before any pair was registered: candidates are fragments whose first frames are
at least 200 frames apart (earlier = target); GT overlap >= 10 %; ranked by the GT rotation angle
(ties: the longer translation); a candidate is skipped when a pair already taken has a target and
a source each starting less than 50 frames from its own; the first 10 are kept. GT is
target_from_source = inv(P_target_first) * P_source_first (camera-to-world frame poses).
"""
import math
import os
import sys
import tomllib

MIN_GAP = 200
MIN_OVERLAP = 10.0
SAME_PLACE = 50
KEEP = 10


def pose(root, seq, i):
    path = os.path.join(root, seq, f"frame-{i:06d}.pose.txt")
    rows = [list(map(float, l.split())) for l in open(path) if l.strip()]
    if len(rows) != 4 or any(len(r) != 4 for r in rows):
        sys.exit(f"{path}: expected a 4x4 matrix")
    return rows


def relative(a, b):
    """(rotation angle in degrees, translation in metres) of inv(a) * b."""
    trace = sum(a[k][i] * b[k][i] for i in range(3) for k in range(3))
    angle = math.degrees(math.acos(max(-1.0, min(1.0, (trace - 1.0) / 2.0))))
    return angle, math.dist([a[i][3] for i in range(3)], [b[i][3] for i in range(3)])


def main():
    if len(sys.argv) != 4:
        sys.exit(__doc__)
    cand_path, tsv_path, out_path = sys.argv[1:]
    root = os.environ.get("CGENREG_DATA")
    if not root:
        sys.exit("set CGENREG_DATA to the data folder")
    with open(cand_path, "rb") as fh:
        cand = tomllib.load(fh)
    frags = {f["id"]: f for f in cand["fragments"]}
    overlap = {}
    for line in open(tsv_path):
        if line.startswith("#") or not line.strip():
            continue
        cols = line.rstrip("\n").split("\t")
        if len(cols) < 5:
            sys.exit(f"{tsv_path}: expected 6 tab-separated columns, got {line!r}")
        target, source = cols[0].split("/")[-1].split("-")
        overlap[(target, source)] = float(cols[4])
    rows = []
    for p in cand["pairs"]:
        t, s = frags[p["target"]], frags[p["source"]]
        gap = s["first"] - t["first"]
        o = overlap.get((p["target"], p["source"]))
        if o is None:
            sys.exit(f"{tsv_path}: no overlap for pair {p['target']}-{p['source']}")
        if gap < MIN_GAP or o < MIN_OVERLAP:
            continue
        angle, dist = relative(pose(root, t["sequence"], t["first"]),
                               pose(root, s["sequence"], s["first"]))
        rows.append((angle, dist, gap, o, p["target"], p["source"], t["first"], s["first"]))
    rows.sort(key=lambda r: (-r[0], -r[1]))
    kept = []
    for r in rows:
        if any(abs(r[6] - k[6]) < SAME_PLACE and abs(r[7] - k[7]) < SAME_PLACE for k in kept):
            continue
        kept.append(r)
        if len(kept) == KEEP:
            break
    used = {k[4] for k in kept} | {k[5] for k in kept}
    out = [
        "# EVALUATED set (docs/ablation.md, \"Revisits\"), written by studies/revisit/revisit_set.sh: the",
        "# hardest loop closures of the 7-Scenes redkitchen sequence. Fragments of 50 raw frames",
        "# starting at frame 50k+o (o = 10, 20, 30, 40), each in the camera frame of its first frame.",
        f"# Pairs: first frames >= {MIN_GAP} apart, GT overlap >= {MIN_OVERLAP:g} %, largest GT rotation first,",
        f"# no two pairs within {SAME_PLACE} frames at both ends, the first {KEEP}.",
        "# GT: gt_poses = true, target_from_source = inv(P_target_first) * P_source_first.",
        'name = "redkitchen-revisit"',
        'root = "$CGENREG_DATA"',
        "",
        "[fragment_options]",
    ]
    for k, v in cand["fragment_options"].items():
        out.append(f"{k} = {v!r}".replace("'", '"'))
    for f in cand["fragments"]:
        if f["id"] in used:
            out += ["", "[[fragments]]", f'id = "{f["id"]}"', f'sequence = "{f["sequence"]}"',
                    f"first = {f['first']}", f"count = {f['count']}"]
    for angle, dist, gap, o, t, s, _, _ in kept:
        split = "3DMatch-like" if o > 30 else "3DLoMatch-like"
        out += ["", "[[pairs]]",
                f"# GT rotation {angle:.1f} deg, translation {dist:.2f} m, {gap} frames apart, overlap {o:.1f} %",
                f'target = "{t}"', f'source = "{s}"', f'split = "{split}"', "gt_poses = true"]
    with open(out_path, "w") as fh:
        fh.write("\n".join(out) + "\n")
    for angle, dist, gap, o, t, s, _, _ in kept:
        print(f"{t}-{s}\t{angle:.1f} deg\t{dist:.2f} m\t{gap} frames\t{o:.1f} %")
    print(f"wrote {out_path}: {len(kept)} pairs of {len(rows)} candidates", file=sys.stderr)


if __name__ == "__main__":
    main()
