#!/usr/bin/env bash
# The whole-redkitchen split study (README.md): manifests, then the runs it names, each resumable
# (bench --json resumes a run cut short).
#   bash studies/redkitchen-split/run.sh STEP...   # split dev dev-image eval eval-xfeat eval-image
# Env: CGENREG_DATA (the data folder), CGENREG_BIN (default target/release/cgenreg),
#      CACHE (default target/redkitchen-split/cache), NICE (default 10).
set -euo pipefail
root="$(cd "$(dirname "$0")/../.." && pwd)"
cd "$root"
here=studies/redkitchen-split
bin="${CGENREG_BIN:-target/release/cgenreg}"
work=target/redkitchen-split
cache="${CACHE:-$work/cache}"
nice_n="${NICE:-10}"
mkdir -p "$work" "$here/results"
bench() { # name, manifest, bench options
  local name="$1" manifest="$2"
  shift 2
  echo "== $name: cgenreg bench $manifest $* --json $here/results/$name.json" >&2
  /usr/bin/time -f "$name: %e s wall, %U s user, %S s system" \
    nice -n "$nice_n" "$bin" bench "$manifest" "$@" --cache-dir "$cache" \
    --json "$here/results/$name.json" >"$work/$name.txt"
  sed -n '/^Per benchmark/,/^$/p' "$work/$name.txt"
}
for step in "$@"; do
  case "$step" in
  split)
    [ -f target/redkitchen-full/redkitchen-full.toml ] || STEPS=manifest bash scripts/redkitchen_full.sh
    python3 "$here/split.py" target/redkitchen-full/redkitchen-full.toml "$work/dev.toml" "$work/eval.toml"
    ;;
  dev) bench dev-alike "$work/dev.toml" --wfm builtin --vfm alike ;;
  dev-image) bench dev-alike-image "$work/dev.toml" --wfm builtin --vfm alike --fusion image ;;
  eval) bench eval-alike "$work/eval.toml" --wfm builtin --vfm alike ;;
  eval-xfeat) bench eval-xfeat "$work/eval.toml" --wfm builtin --vfm xfeat ;;
  eval-image) bench eval-alike-image "$work/eval.toml" --wfm builtin --vfm alike --fusion image ;;
  *) echo "run.sh: unknown step $step (split dev dev-image eval eval-xfeat eval-image)" >&2; exit 2 ;;
  esac
done
