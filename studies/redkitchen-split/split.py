#!/usr/bin/env python3
"""Split the whole-redkitchen manifest (`cgenreg dataset 3dmatch` output) into the development and the evaluated
part by the rule of README.md: a pair is development when both of its fragments are in 0-29, evaluated otherwise.
The fragment numbers are read from each pair's `gt_entry` (the gt.log entry `i j`), so alias fragments (`<k>lo`)
fall where their fragment does.

    python3 split.py FULL.toml DEV.toml EVAL.toml
"""
import re
import sys
import tomllib

DEV_LAST = 29  # the rule: both fragments in 0..=DEV_LAST


def part(i: int, j: int) -> str:
    return "development" if i <= DEV_LAST and j <= DEV_LAST else "evaluated"


def main() -> int:
    if len(sys.argv) != 4:
        print(__doc__, file=sys.stderr)
        return 2
    full, dev_out, eval_out = sys.argv[1:]
    text = open(full, encoding="utf-8").read()
    parsed = tomllib.loads(text)  # a malformed manifest fails here, naming the line
    pairs = parsed.get("pairs", [])
    # Blocks are separated by blank lines; every `[[pairs]]` block is one pair, in order.
    blocks = text.split("\n\n")
    pair_blocks = [b for b in blocks if b.lstrip().startswith("[[pairs]]")]
    if len(pair_blocks) != len(pairs):
        print(f"{full}: {len(pairs)} pairs but {len(pair_blocks)} [[pairs]] blocks", file=sys.stderr)
        return 1
    keep = {"development": [], "evaluated": []}
    for block, pair in zip(pair_blocks, pairs):
        entry = pair.get("gt_entry")
        if not (isinstance(entry, list) and len(entry) == 2):
            print(f"{full}: pair {pair.get('target')}-{pair.get('source')}: no gt_entry [i, j]", file=sys.stderr)
            return 1
        keep[part(*entry)].append(block)
    head = [b for b in blocks if not b.lstrip().startswith("[[pairs]]")]
    for name, out in (("development", dev_out), ("evaluated", eval_out)):
        rule = (f"# The {name} part of the whole-redkitchen split (studies/redkitchen-split/README.md): "
                + ("both fragments in 0-29." if name == "development" else "at least one fragment in 30-59."))
        body = "\n\n".join([rule + "\n" + head[0]] + head[1:] + keep[name]) + "\n"
        body = re.sub(r"\n{3,}", "\n\n", body)
        with open(out, "w", encoding="utf-8") as f:
            f.write(body)
        per = {}
        for b in keep[name]:
            split = re.search(r'split = "([^"]+)"', b)
            per[split.group(1) if split else "?"] = per.get(split.group(1) if split else "?", 0) + 1
        print(f"{out}: {name}, {len(keep[name])} pairs {per}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
