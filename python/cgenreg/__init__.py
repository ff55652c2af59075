"""cgenreg: training-free point-cloud registration by the C-GenReg method, from Python.

The same pipeline as the ``cgenreg`` command line and the inspector: keyword settings are the
command line's options (``voxel=0.1`` is ``--voxel 0.1``; see :func:`settings`), results are NumPy
arrays, and errors are exceptions carrying the library's messages (:mod:`cgenreg.errors`).
Computation releases the GIL.

Transforms are named by direction: ``target_from_source`` maps source points into the target
frame, ``p_target = T @ p_source``.
"""

from __future__ import annotations

import json
import os
from typing import Any, Dict, List, NamedTuple, Optional, Tuple, Union

import numpy as np

from . import _cgenreg
from ._cgenreg import Result
from ._options import to_options
from .bench import load_bench
from .errors import CgenregError, FileError, FormatError, InvalidInput
from .inspector import inspect, screenshot

__all__ = [
    "Result",
    "Estimate",
    "register",
    "register_pair",
    "settings",
    "read_cloud",
    "write_cloud",
    "fpfh",
    "match_then_fuse",
    "sc2pcr",
    "estimate",
    "load_bench",
    "manifest_pairs",
    "inspect",
    "screenshot",
    "CgenregError",
    "InvalidInput",
    "FormatError",
    "FileError",
]

__version__ = _cgenreg.VERSION

PathLike = Union[str, "os.PathLike[str]"]


def _is_path(x: Any) -> bool:
    return isinstance(x, (str, os.PathLike))


def _f32(a: Any, what: str, cols: Optional[int] = None) -> np.ndarray:
    """`a` as a C-contiguous float32 array: no copy when it already is one."""
    arr = np.asarray(a)
    if arr.ndim != 2 or (cols is not None and arr.shape[1] != cols):
        shape = "(N, %d)" % cols if cols is not None else "(N, D)"
        raise InvalidInput(
            "invalid input: %s: expected a %s array, found shape %s" % (what, shape, arr.shape)
        )
    if not np.issubdtype(arr.dtype, np.number):
        raise InvalidInput(
            "invalid input: %s: expected a numeric array, found dtype %s" % (what, arr.dtype)
        )
    return np.ascontiguousarray(arr, dtype=np.float32)


def _vec(a: Any, dtype: Any, what: str) -> Optional[np.ndarray]:
    if a is None:
        return None
    arr = np.asarray(a)
    if arr.ndim != 1:
        raise InvalidInput(
            "invalid input: %s: expected a 1-D array, found shape %s" % (what, arr.shape)
        )
    return np.ascontiguousarray(arr, dtype=dtype)


def settings(**params: Any) -> Dict[str, Any]:
    """The pipeline's settings (its ``RegisterParams``, as a dict) for these keyword settings.

    Every keyword is a ``cgenreg register`` option with ``_`` for ``-`` (``voxel``, ``tau_img``,
    ``selection``, ``estimator``, ``wfm``, ``vfm``, ``k``, ...); what is not given takes the command
    line's default. ``settings()`` gives the defaults.
    """
    return json.loads(_cgenreg.settings(to_options(params)))


def register(
    source: Union[PathLike, np.ndarray],
    target: Union[PathLike, np.ndarray],
    gt: Union[None, PathLike, np.ndarray] = None,
    *,
    source_intensity: Optional[np.ndarray] = None,
    target_intensity: Optional[np.ndarray] = None,
    **params: Any,
) -> Result:
    """Register ``source`` onto ``target``; what ``cgenreg register --source --target`` does.

    ``source``/``target``: two cloud files (any reader of the command line: .ply .pcd .npy .pth
    .bin .xyz .txt .pts) or two (N, 3) arrays (float32 C-contiguous arrays are read without a
    NumPy copy; others are converted). ``gt``: ground truth ``target_from_source``, a file
    (4x4 text or .npy) or a (4, 4) array; with it the result has ``rre_deg``/``rte_m``.
    ``source_intensity``/``target_intensity``: per-point intensity for arrays (it makes a cloud
    LiDAR-like for the image branch's virtual camera). ``**params``: ``cgenreg register``
    options, e.g. ``voxel=0.05``, ``wfm="builtin"`` (image branch), ``no_cache=True``.
    """
    opts = to_options(params)
    if _is_path(source) and _is_path(target):
        if source_intensity is not None or target_intensity is not None:
            raise InvalidInput(
                "invalid input: source_intensity/target_intensity are for arrays; a file's "
                "intensity is read from the file"
            )
        if gt is not None and not _is_path(gt):
            gt_arr = np.asarray(gt, dtype=np.float64)
            src, _, _, _ = _cgenreg.read_cloud(os.fspath(source))
            tgt, _, _, _ = _cgenreg.read_cloud(os.fspath(target))
            return register(src, tgt, gt_arr, **params)
        return _cgenreg.register_files(
            os.fspath(source), os.fspath(target), None if gt is None else os.fspath(gt), opts
        )
    if _is_path(source) or _is_path(target):
        raise InvalidInput(
            "invalid input: give source and target both as files or both as arrays"
        )
    gt_arr = None
    if gt is not None:
        if _is_path(gt):
            raise InvalidInput(
                "invalid input: gt: for arrays give the ground truth as a (4, 4) array"
            )
        gt_arr = np.ascontiguousarray(gt, dtype=np.float64)
    return _cgenreg.register_arrays(
        _f32(source, "source", 3),
        _f32(target, "target", 3),
        gt_arr,
        opts,
        _vec(source_intensity, np.float32, "source_intensity"),
        _vec(target_intensity, np.float32, "target_intensity"),
    )


def register_pair(manifest: PathLike, pair_id: str, **params: Any) -> Result:
    """Register one pair of a dataset manifest: ``cgenreg register --manifest M --pair ID``.

    With a manifest the pair's sensor frames are known, so ``wfm="oracle"`` (real colour),
    ``"builtin"`` or ``"cached"`` (``wfm_dir``, ``wfm_spec``) run the image branch on them.
    """
    return _cgenreg.register_pair(os.fspath(manifest), str(pair_id), to_options(params))


def manifest_pairs(manifest: PathLike) -> List[Dict[str, Any]]:
    """The pairs of a dataset manifest, read by the library: dicts with ``id``, ``split``,
    ``source`` and ``target`` (fragment ids) and ``gt`` (the (4, 4) ``target_from_source``, or
    None)."""
    return [
        {"id": i, "split": s, "source": a, "target": b, "gt": g}
        for (i, s, a, b, g) in _cgenreg.manifest_pairs(os.fspath(manifest))
    ]


def read_cloud(
    path: PathLike, extras: bool = False
) -> Union[np.ndarray, Tuple[np.ndarray, Dict[str, Optional[np.ndarray]]]]:
    """Read a cloud with the command line's readers (chosen by extension).

    Returns the points as an (N, 3) float64 array (the library stores float32; the values are
    exact). With ``extras=True`` also a dict with ``intensity`` (N,) float32, ``colors`` (N, 3)
    uint8 and ``normals`` (N, 3) float32, each None when the file has none.
    """
    pts, intensity, colors, normals = _cgenreg.read_cloud(os.fspath(path))
    if extras:
        return pts, {"intensity": intensity, "colors": colors, "normals": normals}
    return pts


def write_cloud(
    path: PathLike,
    points: np.ndarray,
    intensity: Optional[np.ndarray] = None,
    *,
    force: bool = False,
) -> None:
    """Write points with the library's writers: .ply (binary), .npy ((N, 3) float32) or
    .xyz/.txt/.pts (text). Points are stored as float32.

    The command line's output guard: the folder must exist; a link, FIFO, device or folder is
    refused; the file is written to a temporary file beside it and renamed. An existing file is
    replaced only when it is a PLY this package wrote (``.npy`` and text files carry no mark of
    who wrote them), else only with ``force=True``."""
    _cgenreg.write_cloud(
        os.fspath(path),
        _f32(points, "points", 3),
        _vec(intensity, np.float32, "intensity"),
        bool(force),
    )


def fpfh(points: np.ndarray, voxel: float = 0.05) -> Tuple[np.ndarray, np.ndarray]:
    """The pipeline's geometric branch of one cloud (the ``fpfh`` stage of ``register``).

    Voxel downsampling at ``voxel`` metres, normals (radius 2 voxel, 30 neighbours) oriented to
    the origin, FPFH (radius 5 voxel). Returns the keypoints (K, 3) float32 and their features
    (K, 33) float32, both handed over from the library without a copy.
    """
    return _cgenreg.fpfh(_f32(points, "points", 3), float(voxel))


def match_then_fuse(
    source_geo: np.ndarray,
    target_geo: np.ndarray,
    source_img: Optional[np.ndarray] = None,
    target_img: Optional[np.ndarray] = None,
    source_valid: Optional[np.ndarray] = None,
    target_valid: Optional[np.ndarray] = None,
    **params: Any,
) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Similarity, calibration, Match-then-Fuse and selection, as ``register`` runs them.

    ``source_geo`` (N, D) / ``target_geo`` (M, D): geometric features (e.g. from :func:`fpfh`).
    ``source_img``/``target_img``: per-point image descriptors (optional), with their validity
    (bool (N,) / (M,); default all valid). Without image descriptors only the geometric branch
    is calibrated and selected. ``**params``: the fusion options of ``cgenreg register``
    (``calibration``, ``tau_img``, ``tau_geo``, ``fusion``, ``prior``, ``selection``, ``topk``,
    ``reference``); the default selection is ``nn`` for one branch and ``mutual`` for two.

    Returns (source index uint32, target index uint32, score float32), best first.
    """
    img = source_img is not None or target_img is not None
    return _cgenreg.match_then_fuse(
        _f32(source_geo, "source_geo"),
        _f32(target_geo, "target_geo"),
        to_options(params),
        _f32(source_img, "source_img") if source_img is not None else None,
        _vec(source_valid, np.bool_, "source_valid") if img else None,
        _f32(target_img, "target_img") if target_img is not None else None,
        _vec(target_valid, np.bool_, "target_valid") if img else None,
    )


class Estimate(NamedTuple):
    """A pose estimate: ``target_from_source`` (4, 4) float64, the indices of the
    correspondences kept as inliers (uint64), the method that produced it and a warning (None
    when the estimate can be trusted)."""

    target_from_source: np.ndarray
    inliers: np.ndarray
    method: str
    warning: Optional[str]


def estimate(
    src_xyz: np.ndarray,
    tgt_xyz: np.ndarray,
    scores: Optional[np.ndarray] = None,
    estimator: str = "sc2pcr",
) -> Estimate:
    """The pipeline's pose estimator on correspondences ``src_xyz[i] <-> tgt_xyz[i]``.

    ``estimator``: ``sc2pcr`` (falls back to weighted SVD when it fails, as the pipeline does;
    ``method`` and ``warning`` then say so), ``ransac`` or ``svd``. ``scores`` weigh the
    correspondences in weighted SVD. (K, 3) float32 C-contiguous inputs are read in place.
    """
    src = _f32(src_xyz, "src_xyz", 3)
    tgt = _f32(tgt_xyz, "tgt_xyz", 3)
    t, inl, method, warning = _cgenreg.estimate(
        src, tgt, _vec(scores, np.float32, "scores"), to_options({"estimator": estimator})
    )
    return Estimate(t, inl, method, warning)


def sc2pcr(
    src_xyz: np.ndarray, tgt_xyz: np.ndarray, scores: Optional[np.ndarray] = None
) -> Estimate:
    """SC2-PCR on correspondences ``src_xyz[i] <-> tgt_xyz[i]`` (the pipeline's estimator
    stage with its default parameters); see :func:`estimate`."""
    return estimate(src_xyz, tgt_xyz, scores, "sc2pcr")
