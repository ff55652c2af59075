"""Shared set-up of the Python package's tests: the staged data (``$CGENREG_DATA`` or
``../shared/data`` beside the repository; under ``CI=true`` missing data fails, never skips)
and the ``cgenreg`` binary whose results the package must reproduce."""

from __future__ import annotations

import json
import math
import os
import subprocess
from pathlib import Path
from typing import Any, List

import pytest

REPO = Path(__file__).resolve().parents[2]
STAGED = REPO / "assets" / "manifests" / "redkitchen-staged.toml"


def _ci() -> bool:
    return os.environ.get("CI") == "true"


@pytest.fixture(scope="session")
def data_root() -> Path:
    env = os.environ.get("CGENREG_DATA")
    for p in ([Path(env)] if env else []) + [REPO.parent / "shared" / "data"]:
        if p.is_dir():
            os.environ["CGENREG_DATA"] = str(p)  # the manifests' root
            return p
    if _ci():
        pytest.fail("CI=true but the real test data was not found at $CGENREG_DATA or ../shared/data")
    pytest.skip("real data not found (set CGENREG_DATA)")


@pytest.fixture(scope="session")
def cli_binary() -> Path:
    """The command line to compare with: $CGENREG_TEST_BIN, else the build folder's."""
    env = os.environ.get("CGENREG_TEST_BIN")
    cands = [Path(env)] if env else [REPO / "target" / "debug" / "cgenreg"]
    for p in cands:
        if p.is_file():
            return p
    if _ci():
        pytest.fail("CI=true but the cgenreg binary was not found (build it with cargo build)")
    pytest.skip("cgenreg binary not built (cargo build)")


def run_cli(binary: Path, args: List[str]) -> Any:
    """`cgenreg <args> --json`, parsed; the argument vector goes to the program as is."""
    out = subprocess.run(
        [str(binary)] + args + ["--json"], check=True, capture_output=True, text=True, timeout=600
    )
    return json.loads(out.stdout)


def close(a: Any, b: Any, rel: float = 1e-12) -> bool:
    """JSON equality where numbers may differ by a relative 1e-12 (the pipeline's parallel
    reductions may move a value by an ulp between two runs)."""
    if isinstance(a, bool) or isinstance(b, bool):
        return a == b
    if isinstance(a, (int, float)) and isinstance(b, (int, float)):
        return a == b or abs(a - b) <= rel * max(abs(a), abs(b), 1.0)
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(close(x, y, rel) for x, y in zip(a, b))
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(close(a[k], b[k], rel) for k in a)
    return a == b


def without_timings(r: Any) -> Any:
    r = dict(r)
    r.pop("total_ms", None)
    r["timings"] = [t["stage"] for t in r["timings"]]
    return r


def finite(x: float) -> bool:
    return x is not None and math.isfinite(x)
