"""The package as safe as the command line: no code from the working directory runs, outputs
are guarded and atomic, an allocation that cannot succeed is a MemoryError, Ctrl-C stops a long
call, and the screenshot helper neither hangs nor starts itself forever."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

import cgenreg
from conftest import REPO

DEMO = REPO / "assets" / "demo" / "demo.toml"


def _child(code: str, cwd: Path, env: dict = None, **kw) -> subprocess.CompletedProcess:
    """`code` in a fresh interpreter (the package imported from this venv) in `cwd`."""
    e = dict(os.environ)
    e.update(env or {})
    return subprocess.run(
        [sys.executable, "-c", textwrap.dedent(code)],
        cwd=cwd, env=e, capture_output=True, text=True, timeout=kw.pop("timeout", 300), **kw
    )


def test_a_planted_onnxruntime_in_the_working_directory_never_runs(tmp_path):
    """The image branch loads ONNX Runtime; an `onnxruntime.py`, an `onnxruntime/` package and
    a `python3` in the working directory (with `.` on PATH) are never run."""
    marks = [tmp_path / m for m in ("MARK-module", "MARK-package", "MARK-python3")]
    (tmp_path / "onnxruntime.py").write_text("open(%r, 'w').write('ran')\n" % str(marks[0]))
    (tmp_path / "onnxruntime").mkdir()
    (tmp_path / "onnxruntime" / "__init__.py").write_text(
        "open(%r, 'w').write('ran')\n" % str(marks[1])
    )
    py3 = tmp_path / "python3"
    py3.write_text("#!/bin/sh\ntouch '%s'\nexit 1\n" % marks[2])
    py3.chmod(0o755)
    done = _child(
        """
        import cgenreg
        r = cgenreg.register_pair(%r, "synth-room/0-1", wfm="builtin", frames=8, margin=1, k=2,
                                  voxel=0.1, no_cache=True)
        print(r.to_json())
        """ % str(DEMO),
        tmp_path,
        env={"PATH": ".::" + os.environ.get("PATH", "")},
    )
    for m in marks:
        assert not m.exists(), "%s ran: %s" % (m, done.stderr)
    assert done.returncode == 0, done.stderr
    assert "xfeat@" in done.stdout  # XFeat ran on ONNX Runtime: it was looked up, and found


def test_write_cloud_is_guarded_and_atomic(tmp_path):
    pts = np.random.default_rng(3).random((50, 3)).astype(np.float32)
    notes = tmp_path / "notes.ply"
    notes.write_text("my notes")
    fifo = tmp_path / "fifo.ply"
    os.mkfifo(fifo)
    link = tmp_path / "link.ply"
    link.symlink_to(notes)
    null = tmp_path / "null.ply"
    null.symlink_to("/dev/null")
    for target, why in [
        (notes, "force"), (fifo, "FIFO"), (link, "symbolic link"), (null, "symbolic link"),
        (tmp_path / "no" / "such" / "c.ply", "does not exist"),
    ]:
        with pytest.raises(cgenreg.CgenregError, match=why):
            cgenreg.write_cloud(target, pts)
    assert notes.read_text() == "my notes" and link.is_symlink() and fifo.exists()
    assert not (tmp_path / "no").exists()
    # a PLY this package wrote is replaced; one it did not, or any .npy/.xyz, only with force
    own = tmp_path / "own.ply"
    cgenreg.write_cloud(own, pts)
    cgenreg.write_cloud(own, pts[:10])
    assert len(cgenreg.read_cloud(own)) == 10
    arr = tmp_path / "a.npy"
    np.save(arr, np.zeros((3, 3), np.float32))
    with pytest.raises(cgenreg.CgenregError, match="force"):
        cgenreg.write_cloud(arr, pts)
    cgenreg.write_cloud(arr, pts, force=True)
    assert len(cgenreg.read_cloud(arr)) == 50
    cgenreg.write_cloud(notes, pts, force=True)
    assert len(cgenreg.read_cloud(notes)) == 50
    assert not [p for p in os.listdir(tmp_path) if p.endswith(".tmp")]


def test_an_allocation_that_cannot_succeed_is_a_memory_error(tmp_path):
    """Under an address-space limit, registering more points than fit raises MemoryError
    (the interpreter lives on); before, the failed allocation aborted it (SIGABRT)."""
    done = _child(
        """
        import resource
        import numpy as np
        import cgenreg
        page = resource.getpagesize()
        used = int(open("/proc/self/statm").read().split()[0]) * page
        pts = np.zeros((34_000_000, 3), np.float32)  # 408 MB
        pts[:, 0] = np.arange(len(pts), dtype=np.float32)
        # room for the array above and a little more, not for a copy of it
        resource.setrlimit(resource.RLIMIT_AS, (used + 700 * 2**20, resource.RLIM_INFINITY))
        try:
            cgenreg.register(pts, pts, voxel=0.05)
        except MemoryError as e:
            print("MemoryError:", e)
        print("alive")
        """,
        tmp_path,
    )
    assert done.returncode == 0, "status %d: %s" % (done.returncode, done.stderr[-2000:])
    assert "MemoryError: out of memory" in done.stdout and "alive" in done.stdout, done.stdout


def test_ctrl_c_stops_a_long_call_within_a_second(tmp_path):
    """SIGINT during a long in-process command (a bench through the console script's entry
    point, about a minute at a 2 cm voxel) raises KeyboardInterrupt within a second; before,
    the call ran to its end."""
    proc = subprocess.Popen(
        [sys.executable, "-c", textwrap.dedent(
            """
            import sys, time
            from cgenreg import _cli
            print("start", flush=True)
            t = time.time()
            try:
                _cli.main(["bench", %r, "--voxel", "0.02", "--no-cache", "--limit", "1"])
                print("returned after %%.1f s" %% (time.time() - t))
            except KeyboardInterrupt:
                print("interrupted", flush=True)
            """ % str(DEMO)
        )],
        cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    assert proc.stdout.readline().strip() == "start"
    time.sleep(4.0)  # past loading the pair: in FPFH or the similarity bands
    assert proc.poll() is None, "the call ended before the signal: make it longer"
    t = time.monotonic()
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=60)
    waited = time.monotonic() - t
    assert "interrupted" in out, out + err
    assert waited < 1.0, "took %.2f s to stop" % waited


def test_screenshot_times_out_and_never_starts_itself_forever(tmp_path, monkeypatch):
    from cgenreg import inspector

    monkeypatch.setattr(cgenreg._cgenreg, "HAS_GUI", False)
    slow = tmp_path / "slow"
    slow.write_text("#!/bin/sh\nsleep 30\n")
    slow.chmod(0o755)
    t = time.monotonic()
    with pytest.raises(cgenreg.CgenregError, match="did not finish within 1"):
        cgenreg.screenshot(DEMO, out=tmp_path / "x.png", command=[str(slow)], timeout=1)
    assert time.monotonic() - t < 10
    # $CGENREG_BIN naming this package's console script (a wheel without the GUI): the script
    # it hands the command to finds the hand-off in its environment and stops, instead of
    # handing it on to itself forever
    from cgenreg import _cli

    monkeypatch.setenv("CGENREG_BIN", str(Path(sys.executable).parent / "cgenreg"))
    monkeypatch.setenv(inspector.HANDOFF_ENV, "1")
    assert _cli.main(["screenshot", "--out", str(tmp_path / "y.png")]) == 1
    with pytest.raises(cgenreg.CgenregError, match="console script"):
        inspector.inspector_command()


def test_a_temporary_folder_with_characters_outside_the_bmp_works(tmp_path, monkeypatch):
    """The temporary one-pair manifest of inspect()/screenshot() on arrays is valid TOML when
    the temporary folder's name holds a character outside the BMP (and quotes, a backslash)."""
    from cgenreg.inspector import _write_pair

    folder = tmp_path / "tmp \U0001F600 \"q\" \\ \u00e9"
    folder.mkdir()
    pts = np.random.default_rng(5).random((400, 3)).astype(np.float32)
    m = _write_pair(str(folder), pts, pts, np.eye(4))
    pairs = cgenreg.manifest_pairs(m)
    assert [p["id"] for p in pairs] == ["python/target-source"]
    np.testing.assert_array_equal(pairs[0]["gt"], np.eye(4))
