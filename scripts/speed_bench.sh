#!/usr/bin/env bash
# Whole-pair time of the default method (image branch, default `visibility` fusion) and of the
# geometric branch alone, in the same run: cold (each from an empty stage cache of its own, so a
# scan's cached stages are computed by the first pair that uses it) and warm (the same command
# again on that cache), with the ratio method / geometry. One line per run, then the table.
#
#   bash scripts/speed_bench.sh [MANIFEST] [OUT_DIR]
#
# Env: CGENREG_BIN (default target/release/cgenreg), METHOD (the method's bench options,
# default "--wfm builtin --vfm alike"), CGENREG_DATA. OUT_DIR (default target/speed-bench) gets
# the caches and the four run files; it is emptied first. REPORT_ONLY=1 prints the tables of
# the run already in OUT_DIR (an earlier build's, say) without running anything.
set -euo pipefail
cd "$(dirname "$0")/.."
M="${1:-assets/manifests/redkitchen-staged-clouds.toml}"
OUT="${2:-target/speed-bench}"
BIN="${CGENREG_BIN:-target/release/cgenreg}"
read -r -a METHOD <<< "${METHOD:---wfm builtin --vfm alike}"
export CGENREG_DATA="${CGENREG_DATA:-$(cd .. && pwd)/shared/data}"
if [ "${REPORT_ONLY:-0}" != 1 ]; then
rm -rf "$OUT"
mkdir -p "$OUT"
run() { # name, cache folder, then bench options
    local name="$1" cache="$2"; shift 2
    echo "== $name: cgenreg bench $M $* --cache-dir $cache" >&2
    # CPU time of the whole run too: other jobs on the machine inflate wall times
    /usr/bin/time -f "%e %U %S" -o "$OUT/$name.time" \
        "$BIN" bench "$M" "$@" --cache-dir "$OUT/$cache" --json "$OUT/$name.json" \
        > "$OUT/$name.txt" 2> "$OUT/$name.log"
}
run geometry-cold cache-geometry
run method-cold cache-method "${METHOD[@]}"
run geometry-warm cache-geometry
run method-warm cache-method "${METHOD[@]}"
fi
python3 - "$OUT" "$M" "${METHOD[*]}" <<'PY'
import json, statistics, sys
out, manifest, method = sys.argv[1:4]
def load(name):
    d = json.load(open(f"{out}/{name}.json"))
    recs = d["records"]
    t = [r["time_s"] for r in recs]
    ok = sum(1 for r in recs if (r.get("result") or {}).get("success"))
    stages = {}
    for r in recs:
        for s in r.get("stages", []):
            stages[s["stage"]] = stages.get(s["stage"], 0.0) + s["ms"] / 1e3
    wall, user, system = (float(x) for x in open(f"{out}/{name}.time").read().split()[-3:])
    return len(recs), ok, sum(t), statistics.median(t), stages, wall, user + system
print(f"manifest {manifest}; method: bench {method} (default fusion); geometry: bench (no image branch)")
print("| run | pairs | registered | whole-pair time, sum (s) | per pair, mean (s) | per pair, median (s) | method / geometry | process wall (s) | process CPU (s) | method / geometry, CPU |")
print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
for temp in ["cold", "warm"]:
    g = load(f"geometry-{temp}")
    m = load(f"method-{temp}")
    for name, r in [("geometry alone", g), ("method", m)]:
        ratio = f"{m[2] / g[2]:.2f}x" if name == "method" else ""
        cpu = f"{m[6] / g[6]:.2f}x" if name == "method" else ""
        print(f"| {name}, {temp} | {r[0]} | {r[1]} | {r[2]:.1f} | {r[2] / r[0]:.2f} | {r[3]:.2f} | {ratio} | {r[5]:.1f} | {r[6]:.1f} | {cpu} |")
for temp in ["cold", "warm"]:
    m = load(f"method-{temp}")
    top = sorted(m[4].items(), key=lambda kv: -kv[1])[:8]
    print(f"method {temp}, stage totals (s): " + ", ".join(f"{k} {v:.1f}" for k, v in top))
# Where the method's pair goes: per stage, the mean over all pairs and how many computed it
# (the others read the stage cache or the run's memo)
def per_stage(name):
    recs = json.load(open(f"{out}/{name}.json"))["records"]
    total, computed, order = {}, {}, []
    for r in recs:
        for s in r.get("stages", []):
            k = s["stage"]
            if k not in total:
                order.append(k)
            total[k] = total.get(k, 0.0) + s["ms"] / 1e3
            computed[k] = computed.get(k, 0) + (s.get("status") == "computed")
    return len(recs), total, computed, order
print()
print("| stage, mean per pair (s) | cold | pairs that computed it, cold | warm |")
print("|---|---:|---:|---:|")
nc, tc, cc, order = per_stage("method-cold")
nw, tw, _, order_w = per_stage("method-warm")
for k in order + [k for k in order_w if k not in order]:
    print(f"| {k} | {tc.get(k, 0) / nc:.2f} | {cc.get(k, 0)} | {tw.get(k, 0) / nw:.2f} |")
print(f"| whole pair | {load('method-cold')[2] / nc:.2f} | | {load('method-warm')[2] / nw:.2f} |")
PY
