#!/usr/bin/env python3
"""The per-VFM Table-4 tables of docs/ablation.md, generated from the bench JSONs (never typed by
hand): for each VFM (XFeat, ALIKE-t, DISK) and frame source (oracle RGB, built-in shading), one
table per split made by `cgenreg table --split SPLIT FILE...`, with the JSON each row comes from
and the build that wrote it; rows whose JSON is missing or incomplete are listed as not run.
Then, per split, which 3DLoMatch pairs each row registers (so a loss is visible pair by pair).

    python3 studies/ablation/ablation_tables.py [--write]

Prints the markdown; with --write it also replaces the text between the markers
`<!-- vfm-tables:begin -->` and `<!-- vfm-tables:end -->` in docs/ablation.md and writes
studies/ablation/results/vfm/tables.md. Env: CGENREG_BIN (default target/debug/cgenreg)."""
import json
import os
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
BIN = os.environ.get("CGENREG_BIN", os.path.join(ROOT, "target/debug/cgenreg"))
V = "studies/ablation/results/vfm"  # the per-VFM rows (debug build)
I3 = "studies/ablation/results"  # the first XFeat rows (release build, e0bcd09)
BEGIN, END = "<!-- vfm-tables:begin -->", "<!-- vfm-tables:end -->"
SPLITS = ["3DMatch", "3DLoMatch"]
FUSIONS = ["image", "concat", "noisy-or", "noisy-and", "reference"]


def groups():
    """(title, [(row name, JSON path)]) in table order; FPFH rows head every table."""
    mutual = f"{V}/fpfh-mutual.json"  # this build's, else the first XFeat run's row (same code path)
    if load(mutual) is None:
        mutual = f"{I3}/fpfh-mutual.json"
    fpfh = [("FPFH, NN", f"{V}/fpfh-nn.json"), ("FPFH, mutual NN", mutual)]
    out = []
    for wfm, wlabel in [("oracle", "oracle RGB"), ("builtin", "built-in shading (not a WFM)")]:
        for vfm, vlabel in [("xfeat", "XFeat"), ("alike", "ALIKE-t"), ("disk", "DISK")]:
            rows = list(fpfh)
            if vfm == "xfeat":  # the first XFeat run's rows (release build), mutual NN and NN
                for f in FUSIONS[:4]:
                    rows.append((f"{f} (studies/ablation/results, release)", f"{I3}/{wfm}-{f}.json"))
                    if wfm == "oracle":
                        rows.append((f"{f}, NN (studies/ablation/results, release)", f"{I3}/{wfm}-{f}-nn.json"))
                rows.append(("reference", f"{V}/{vfm}-{wfm}-reference.json"))
            else:
                for f in FUSIONS:
                    rows.append((f, f"{V}/{vfm}-{wfm}-{f}.json"))
            out.append((f"{vlabel} on {wlabel}", rows))
    return out


def load(path):
    p = os.path.join(ROOT, path)
    if not os.path.isfile(p):
        return None
    v = json.load(open(p))
    run = v.get("run") or {}
    if run.get("complete") is False:
        return None
    return v


def build_of(v):
    run = v.get("run") or {}
    b = (run.get("identity") or {}).get("binary_blake3")
    return f"debug `{b[:8]}`" if b else "release e0bcd09"


def table(rows, split):
    have = [(n, p, v) for n, p, v in rows
            if v is not None and any(s["split"] == split for s in v["summary"])]
    if not have:
        return []
    cmd = [BIN, "table", "--split", split] + [os.path.join(ROOT, p) for _, p, _ in have]
    lines = subprocess.run(cmd, check=True, capture_output=True, text=True).stdout.splitlines()
    head, rule, body = lines[0], lines[1], lines[2:]
    if len(body) != len(have):
        sys.exit(f"cgenreg table gave {len(body)} rows for {len(have)} files ({split})")
    out = [head + " JSON | build |", rule + "---|---|"]
    for (_, p, v), line in zip(have, body):
        out.append(line + f" `{p}` | {build_of(v)} |")
    return out


def per_pair(rows, split):
    """Which pairs of `split` each row registers (RRE <= 15 deg, RTE <= 30 cm)."""
    have = [(n, v) for n, _, v in rows
            if v is not None and any(r["split"] == split for r in v["pairs"])]
    if not have:
        return []
    ids = [r["id"] for r in have[0][1]["pairs"] if r["split"] == split]
    out = ["| row | " + " | ".join(i.split("/")[-1] for i in ids) + " | ok |",
           "|---|" + "---|" * (len(ids) + 1)]
    for n, v in have:
        by = {r["id"]: r for r in v["pairs"]}
        cells = ["ok" if by.get(i, {}).get("success") else "–" for i in ids]
        out.append(f"| {n} | " + " | ".join(cells) + f" | {cells.count('ok')}/{len(ids)} |")
    return out


def main():
    md = []
    for title, rows in groups():
        rows = [(n, p, load(p)) for n, p in rows]
        missing = [p for _, p, v in rows if v is None]
        md.append(f"#### {title}")
        md.append("")
        for split in SPLITS:
            t = table(rows, split)
            if t:
                md += [f"{split}:", ""] + t + [""]
            part = [p for _, p, v in rows
                    if v is not None and not any(s["split"] == split for s in v["summary"])]
            if t and part:
                md += [f"Not run on {split} (the JSON holds other splits only): "
                       + ", ".join(f"`{p}`" for p in part) + ".", ""]
        t = per_pair(rows, "3DLoMatch")
        if t:
            md += ["3DLoMatch pair by pair (ok = RRE ≤ 15° and RTE ≤ 30 cm):", ""] + t + [""]
        if missing:
            md.append("Not run (no complete JSON): " + ", ".join(f"`{p}`"
                                                              for p in missing) + ".")
            md.append("")
    text = "\n".join(md)
    print(text)
    if "--write" in sys.argv:
        with open(os.path.join(ROOT, V, "tables.md"), "w") as f:
            f.write(text + "\n")
        doc = os.path.join(ROOT, "docs/ablation.md")
        s = open(doc).read()
        if BEGIN in s and END in s:  # docs/ablation.md now shows scripts/tables.py's summary instead
            a, b = s.index(BEGIN) + len(BEGIN), s.index(END)
            open(doc, "w").write(s[:a] + "\n" + text + "\n" + s[b:])


if __name__ == "__main__":
    main()
