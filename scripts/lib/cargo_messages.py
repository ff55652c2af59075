#!/usr/bin/env python3
"""Filter for `cargo ... --message-format=json-render-diagnostics 2>&1` (scripts/test.sh).

Prints what cargo would print for a person (its progress lines and the rendered
diagnostics) and, the moment the library's unit-test binary is linked, a line
`UNIT_TEST_EXE <path>`, so the caller can start those tests while the rest of the build
goes on. Lines that are not cargo's JSON pass through unchanged.
"""
import json
import sys


def main() -> None:
    for line in sys.stdin:
        text = line.rstrip("\n")
        if not text.startswith("{"):
            print(text, flush=True)
            continue
        try:
            msg = json.loads(text)
        except json.JSONDecodeError:
            print(text, flush=True)
            continue
        reason = msg.get("reason")
        if reason == "compiler-message":
            rendered = (msg.get("message") or {}).get("rendered")
            if rendered:
                print(rendered, end="" if rendered.endswith("\n") else "\n", flush=True)
        elif reason == "compiler-artifact":
            target = msg.get("target") or {}
            profile = msg.get("profile") or {}
            exe = msg.get("executable")
            if exe and profile.get("test") and "lib" in target.get("kind", []):
                print(f"UNIT_TEST_EXE {exe}", flush=True)


if __name__ == "__main__":
    main()
