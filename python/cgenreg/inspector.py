"""Opening the inspector (the ``cgenreg`` GUI) from Python, as a separate process."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile
from typing import Any, List, Optional, Sequence, Union

import numpy as np

from . import _cgenreg
from ._options import to_options
from .errors import CgenregError

PathLike = Union[str, "os.PathLike[str]"]

# Set in the environment of a program this package hands a GUI command to (see _cli.main): a
# console script that finds it set was started by itself.
HANDOFF_ENV = "CGENREG_HANDED_OFF"


def _is_native(path: str) -> bool:
    try:
        with open(path, "rb") as f:
            return f.read(4) == b"\x7fELF" or path.endswith(".exe")
    except OSError:
        return False


def inspector_command() -> List[str]:
    """The argument vector that starts the GUI-capable ``cgenreg``.

    ``$CGENREG_BIN`` when set; else this package itself when its extension was built with the
    inspector (``HAS_GUI``); else a native ``cgenreg`` binary on ``PATH`` (the console script this
    package installs is skipped: it has no inspector unless built with it).
    """
    env = os.environ.get("CGENREG_BIN")
    if env:
        if os.environ.get(HANDOFF_ENV):
            # this package's console script handed the command to $CGENREG_BIN, which is the
            # console script again: it would hand it on forever
            raise CgenregError(
                "CGENREG_BIN=%s is this Python package's console script, which has no "
                "inspector: set CGENREG_BIN to the native cgenreg binary built with the GUI" % env
            )
        return [env]
    if _cgenreg.HAS_GUI:
        return [sys.executable, "-m", "cgenreg"]
    for d in os.environ.get("PATH", "").split(os.pathsep):
        p = os.path.join(d, "cgenreg")
        if os.path.isfile(p) and os.access(p, os.X_OK) and _is_native(p):
            return [p]
    raise CgenregError(
        "the inspector needs the cgenreg binary with its GUI: build it with "
        "`cargo install --path .` in the source tree (or `cargo build --release` and set "
        "CGENREG_BIN to target/release/cgenreg); this Python package's extension was built "
        "without the GUI"
    )


def _toml_str(s: str) -> str:
    """``s`` as a TOML basic string. Not ``json.dumps``: it writes a character outside the BMP as
    a surrogate pair (``\\ud83d\\ude00``), which TOML refuses, and leaves DEL unescaped."""
    out = []
    for c in s:
        if c == '"' or c == "\\":
            out.append("\\" + c)
        elif ord(c) < 0x20 or ord(c) == 0x7F:
            out.append("\\u%04X" % ord(c))
        else:
            out.append(c)
    return '"' + "".join(out) + '"'


def _write_pair(
    folder: str, source: np.ndarray, target: np.ndarray, gt: Optional[np.ndarray]
) -> str:
    """Two arrays (and a GT) as a manifest of one pair in ``folder``; returns the manifest."""
    from . import write_cloud

    write_cloud(os.path.join(folder, "source.ply"), source)
    write_cloud(os.path.join(folder, "target.ply"), target)
    lines = [
        'name = "python"',
        "root = %s" % _toml_str(folder),
        "",
        "[[fragments]]",
        'id = "source"',
        'cloud = "source.ply"',
        "",
        "[[fragments]]",
        'id = "target"',
        'cloud = "target.ply"',
        "",
        "[[pairs]]",
        'target = "target"',
        'source = "source"',
    ]
    if gt is not None:
        m = np.asarray(gt, dtype=np.float64).reshape(4, 4)
        with open(os.path.join(folder, "gt.txt"), "w") as f:
            for row in m:
                f.write(" ".join(repr(float(v)) for v in row) + "\n")
        lines.append('gt_file = "gt.txt"')
    manifest = os.path.join(folder, "pair.toml")
    with open(manifest, "w") as f:
        f.write("\n".join(lines) + "\n")
    return manifest


def _pair_manifest(
    manifest: Optional[PathLike],
    pair: Optional[str],
    source: Optional[Any],
    target: Optional[Any],
    gt: Optional[Any],
    what: str,
) -> "tuple[Optional[str], Optional[PathLike], Optional[str]]":
    """A manifest and pair to open: as given, or two clouds (arrays or files, + GT) written to a
    temporary folder. Returns (the temporary folder or None, manifest, pair)."""
    from . import read_cloud

    if source is None and target is None:
        return None, manifest, pair
    if source is None or target is None or manifest is not None:
        raise CgenregError("%s: give manifest (and pair), or source and target" % what)
    tmp = tempfile.mkdtemp(prefix="cgenreg-%s-" % what)
    src = read_cloud(source) if isinstance(source, (str, os.PathLike)) else source
    tgt = read_cloud(target) if isinstance(target, (str, os.PathLike)) else target
    gt_m = None
    if gt is not None:
        if isinstance(gt, (str, os.PathLike)):
            gt_m = np.loadtxt(os.fspath(gt)).reshape(4, 4)
        else:
            gt_m = np.asarray(gt, dtype=np.float64)
    return tmp, _write_pair(tmp, np.asarray(src), np.asarray(tgt), gt_m), "python/target-source"


def inspect(
    manifest: Optional[PathLike] = None,
    pair: Optional[str] = None,
    *,
    source: Optional[Any] = None,
    target: Optional[Any] = None,
    gt: Optional[Any] = None,
    wait: bool = False,
    command: Optional[Sequence[str]] = None,
    **params: Any,
) -> "subprocess.Popen[bytes]":
    """Open the inspector on a manifest pair, or on two clouds (arrays or files).

    ``manifest``/``pair``: as ``cgenreg inspect --manifest M --pair ID`` (e.g. the pair of a
    failed :func:`register_pair`). ``source``/``target`` (+ ``gt``): clouds given as arrays or
    files are written to a temporary manifest of one pair (removed when the inspector exits if
    ``wait=True``; otherwise it stays in the system's temporary folder). ``**params``: the
    same settings as :func:`cgenreg.register` (the inspector's controls start from them).
    The inspector runs as a separate process started with an argument vector (never a shell);
    returns the process (``wait=True`` waits for it to close). ``command`` overrides the
    program (see :func:`inspector_command`).
    """
    tmp, manifest, pair = _pair_manifest(manifest, pair, source, target, gt, "inspect")
    argv = list(command) if command is not None else inspector_command()
    argv.append("inspect")
    if manifest is not None:
        argv += ["--manifest", os.fspath(manifest)]
    if pair is not None:
        argv += ["--pair", str(pair)]
    argv += to_options(params)
    proc = subprocess.Popen(argv)
    if wait:
        proc.wait()
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
    return proc


def screenshot(
    manifest: Optional[PathLike] = None,
    pair: Optional[str] = None,
    *,
    out: PathLike,
    source: Optional[Any] = None,
    target: Optional[Any] = None,
    gt: Optional[Any] = None,
    panel: str = "3d",
    width: int = 1600,
    height: int = 1000,
    result_json: Optional[PathLike] = None,
    force: bool = False,
    command: Optional[Sequence[str]] = None,
    timeout: Optional[float] = 600.0,
    **params: Any,
) -> Optional[dict]:
    """Render the inspector headless to a PNG, on a manifest pair or two clouds (arrays or files).

    As ``cgenreg screenshot``: the pair is registered with ``**params`` (the same settings as
    :func:`cgenreg.register`) and ``panel`` ("3d", "views", "posterior", ...) is drawn at
    ``width`` x ``height`` into ``out`` (a new file, or a PNG to replace; another existing file
    only with ``force``). No window
    opens: this works on a machine without a display (it needs EGL). Returns the registration
    result the picture shows, parsed from ``register --json``'s format, when ``result_json`` is
    given (that file is written too). Runs the GUI-capable binary (see
    :func:`inspector_command`, or ``command``) with an argument vector; a failure raises
    :class:`CgenregError` with the program's message, and so does a program still running after
    ``timeout`` seconds (it is killed; ``None`` waits without a limit).
    """
    tmp, manifest, pair = _pair_manifest(manifest, pair, source, target, gt, "screenshot")
    try:
        argv = list(command) if command is not None else inspector_command()
        argv.append("screenshot")
        if manifest is not None:
            argv += ["--manifest", os.fspath(manifest)]
        if pair is not None:
            argv += ["--pair", str(pair)]
        argv += ["--panel", str(panel), "--out", os.fspath(out)]
        argv += ["--width", str(int(width)), "--height", str(int(height))]
        if result_json is not None:
            argv += ["--result-json", os.fspath(result_json)]
        if force:
            argv.append("--force")
        argv += to_options(params)
        env = dict(os.environ)
        env[HANDOFF_ENV] = "1"
        try:
            done = subprocess.run(argv, capture_output=True, text=True, timeout=timeout, env=env)
        except subprocess.TimeoutExpired:
            raise CgenregError(
                "screenshot: %s did not finish within %s s and was stopped (pass a larger "
                "timeout, or None)" % (argv[0], timeout)
            ) from None
        if done.returncode != 0:
            msg = done.stderr.strip() or done.stdout.strip()
            raise CgenregError("screenshot failed (exit %d): %s" % (done.returncode, msg))
        if result_json is None:
            return None
        with open(os.fspath(result_json)) as f:
            return json.load(f)
    finally:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
