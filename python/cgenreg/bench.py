"""Reading ``cgenreg bench --json`` (and ``cgenreg merge``) outputs."""

from __future__ import annotations

import json
import os
from typing import Any, Dict, Optional, Union

import numpy as np

from . import _cgenreg

_COLUMNS = ("rre_deg", "rte_m", "inlier_ratio", "time_s")


def load_bench(path: Union[str, "os.PathLike[str]"], as_frame: Optional[bool] = None) -> Dict[str, Any]:
    """A bench run, checked by the library's reader (the one ``cgenreg diff`` and the inspector's
    Compare tab use; errors name the file and the field).

    Returns a dict: ``params`` (the run's ``RegisterParams``), ``identity``, ``manifest``,
    ``label``, ``pairs`` (one dict per pair: id, split, source, target, rre_deg, rte_m,
    inlier_ratio, success, time_s, error), and ``arrays``: the numeric columns as float64
    arrays (NaN where a pair has no value) and ``success`` as a bool array. With
    ``as_frame=True``, or by default when pandas is installed, ``pairs`` is a
    ``pandas.DataFrame``.
    """
    run = json.loads(_cgenreg.load_bench(os.fspath(path)))
    rows = run["pairs"]
    arrays = {
        c: np.array([np.nan if r[c] is None else r[c] for r in rows], dtype=np.float64)
        for c in _COLUMNS
    }
    arrays["success"] = np.array([bool(r["success"]) for r in rows], dtype=bool)
    run["arrays"] = arrays
    if as_frame is None:
        try:
            import pandas  # noqa: F401

            as_frame = True
        except ImportError:
            as_frame = False
    if as_frame:
        import pandas as pd

        run["pairs"] = pd.DataFrame(rows)
    return run
