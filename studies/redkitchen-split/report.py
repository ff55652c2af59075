#!/usr/bin/env python3
"""Tables of the whole-redkitchen split study from its committed run files (README.md).

    python3 studies/redkitchen-split/report.py [PART ...]   # development evaluated (default: those with results)

For each part: the runs' recall per benchmark (RR at the run's criterion, the official RMSE recall, mean RE / TE),
then the pairs geometry alone registers that the default loses, and the pairs it gains, with each candidate's
visibility share F (the run file's fusion report) and the image branch's own pose error (its `--fusion image` run).
Geometry alone is the committed whole-benchmark run (docs/results/redkitchen-full/cgenreg-geometry.json).
"""
import json
import os
import re
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
GEOMETRY = os.path.join(ROOT, "docs/results/redkitchen-full/cgenreg-geometry.json")
PARTS = {
    "development": {"default (ALIKE-t)": "dev-alike", "image alone (ALIKE-t)": "dev-alike-image"},
    "evaluated": {
        "default (ALIKE-t)": "eval-alike",
        "default (XFeat)": "eval-xfeat",
        "image alone (ALIKE-t)": "eval-alike-image",
    },
}
DEFAULT = "default (ALIKE-t)"
# The candidate rule frozen after the development part (README.md, "Development study"): keep the geometry pose
# unless another candidate's F exceeds geometry's by at least MARGIN. Its outcome is exact from a default run file:
# the geometry candidate's pose is the geometry-alone pose (equal on every development pair that kept it).
MARGIN = 0.03
CANDIDATE = f"geometry unless beaten by F + {MARGIN} (candidate, computed)"
IMAGE = "image alone (ALIKE-t)"


def load(name):
    path = os.path.join(HERE, "results", name + ".json")
    if not os.path.exists(path):
        return None
    with open(path, encoding="utf-8") as f:
        return json.load(f)


def by_id(run):
    return {p["id"]: p for p in run["pairs"]}


def shares(fusion):
    """The candidates' F shares and the kept candidate from a visibility report line."""
    if not fusion:
        return None, {}
    kept = re.search(r"kept the (\S+) pose", fusion)
    f = dict(re.findall(r"(union|geometry|Noisy-AND|image) (\d\.\d+)", fusion))
    return (kept.group(1) if kept else None), {k: float(v) for k, v in f.items()}


def rmse_recall(pairs):
    counted = [p for p in pairs if p.get("rmse_counted")]
    if not counted:
        return None
    ok = sum(1 for p in counted if p.get("rmse_m") is not None and p["rmse_m"] < 0.2)
    return 100.0 * ok / len(counted)


def row(name, pairs, bench):
    sel = [p for p in pairs if p["split"] == bench]
    ok = [p for p in sel if p.get("success")]
    rr = 100.0 * len(ok) / len(sel) if sel else float("nan")
    off = rmse_recall(sel)
    re_mean = sum(p["rre_deg"] for p in ok) / len(ok) if ok else float("nan")
    te_mean = sum(p["rte_m"] for p in ok) / len(ok) if ok else float("nan")
    t = sum(p.get("time_s", 0.0) for p in sel) / len(sel) if sel else float("nan")
    off_s = f"{off:.1f} %" if off is not None else "-"
    return (f"| {name} | {bench} | {len(sel)} | {len(ok)} | {rr:.1f} % | {off_s} | {re_mean:.2f}° / "
            f"{100 * te_mean:.1f} cm | {t:.2f} |")


def with_margin(default, geometry):
    """The default run's pairs as the margin rule would have kept them."""
    out = []
    for p in default["pairs"]:
        kept, f = shares(p.get("fusion"))
        if kept and kept != "geometry" and "geometry" in f and f[kept] - f["geometry"] < MARGIN:
            p = dict(geometry[p["id"]], time_s=p.get("time_s", 0.0), fusion=p.get("fusion"))
        out.append(p)
    return {"pairs": out}


def part_report(part, details=True, out=None):
    """The part's tables as markdown lines (appended to `out`); False when its default run is missing."""
    out = [] if out is None else out
    print = lambda *a: out.append(" ".join(str(x) for x in a) if a else "")  # noqa: A001
    runs = {k: load(v) for k, v in PARTS[part].items()}
    if runs[DEFAULT] is None:
        return False
    ids = [p["id"] for p in runs[DEFAULT]["pairs"]]
    geo_all = by_id(json.load(open(GEOMETRY, encoding="utf-8")))
    geo = [geo_all[i] for i in ids]
    runs[CANDIDATE] = with_margin(runs[DEFAULT], geo_all)
    print(f"### {part}: {len(ids)} pairs\n")
    print("| run | benchmark | pairs | registered | RR (15°, 30 cm) | official RR (RMSE) | RE / TE mean | s/pair |")
    print("|---|---|---:|---:|---:|---:|---|---:|")
    for bench in ("3DMatch", "3DLoMatch"):
        print(row("geometry alone (committed run)", geo, bench))
        for name, run in runs.items():
            if run is not None:
                print(row(name, run["pairs"], bench))
    print()
    d = by_id(runs[DEFAULT])
    img = by_id(runs[IMAGE]) if runs[IMAGE] else {}
    c = by_id(runs[CANDIDATE])
    lost = [i for i in ids if geo_all[i].get("success") and not d[i].get("success")]
    gained = [i for i in ids if not geo_all[i].get("success") and d[i].get("success")]
    c_lost = sum(1 for i in ids if geo_all[i].get("success") and not c[i].get("success"))
    c_gained = sum(1 for i in ids if not geo_all[i].get("success") and c[i].get("success"))
    print(f"The candidate rule: {c_lost} lost, {c_gained} gained against geometry alone "
          f"(the default: {len(lost)} lost, {len(gained)} gained).\n")
    if not details:
        return True
    for title, sel in (("Lost (geometry registers, the default does not)", lost),
                       ("Gained (the default registers, geometry does not)", gained)):
        print(f"#### {title}: {len(sel)}\n")
        if not sel:
            continue
        print("| pair | split | kept | F union / geometry / Noisy-AND / image | default RRE, RTE | geometry RRE, RTE | image alone RRE, RTE |")
        print("|---|---|---|---|---|---|---|")
        for i in sel:
            kept, f = shares(d[i].get("fusion"))
            fs = " / ".join(f"{f[k]:.3f}" if k in f else "-" for k in ("union", "geometry", "Noisy-AND", "image"))

            def err(p):
                if p is None or p.get("rre_deg") is None:
                    return "-"
                return f"{p['rre_deg']:.1f}°, {100 * p['rte_m']:.0f} cm"
            print(f"| {i.split('/')[-1]} | {d[i]['split']} | {kept} | {fs} | {err(d[i])} | {err(geo_all[i])} | {err(img.get(i))} |")
        print()
    return True


def main():
    parts = sys.argv[1:] or list(PARTS)
    for p in parts:
        if p not in PARTS:
            print(f"report.py: unknown part {p} ({', '.join(PARTS)})", file=sys.stderr)
            return 2
        lines = []
        part_report(p, out=lines)
        print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
