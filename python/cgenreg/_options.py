"""Keyword arguments as `cgenreg register` options: one representation of every setting.

``voxel=0.1`` is ``--voxel 0.1``, ``tau_img=0.05`` is ``--tau-img 0.05``, ``wfm="builtin"`` is
``--wfm builtin``, ``reference=True`` is ``--reference``, ``cosmos_cmd=["torchrun", ...]`` repeats
``--cosmos-cmd``. The library parses them with the command line's own parser: the same names,
defaults, checks and error messages.
"""

from __future__ import annotations

import os
from typing import Any, Dict, List


def to_options(params: Dict[str, Any]) -> List[str]:
    out: List[str] = []
    for key, value in params.items():
        if value is None or value is False:
            continue
        flag = "--" + key.replace("_", "-")
        if value is True:
            out.append(flag)
        elif isinstance(value, (list, tuple)):
            for v in value:
                out += [flag, _text(v)]
        else:
            out += [flag, _text(value)]
    return out


def _text(v: Any) -> str:
    if isinstance(v, os.PathLike):
        return os.fspath(v)
    if isinstance(v, float):
        return repr(float(v))  # round-trips exactly (also for numpy.float64)
    return str(v)
