"""Stage functions compose to `register`'s result; bench files, the console script and the
inspector's argument vector."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import cgenreg
from conftest import STAGED, close, run_cli


def _demo(data_root):
    d = data_root / "3dmatch-redkitchen" / "geotransformer-demo"
    return (
        cgenreg.read_cloud(d / "src.npy"),
        cgenreg.read_cloud(d / "ref.npy"),
        np.load(d / "gt.npy"),
    )


def test_fpfh_match_then_fuse_sc2pcr_equal_register(data_root):
    src, ref, gt = _demo(data_root)
    res = cgenreg.register(src, ref, gt, voxel=0.05)
    kp_s, f_s = cgenreg.fpfh(src, 0.05)
    kp_t, f_t = cgenreg.fpfh(ref, 0.05)
    np.testing.assert_array_equal(kp_s, res.source_keypoints)
    np.testing.assert_array_equal(kp_t, res.target_keypoints)
    assert f_s.shape == (len(kp_s), 33) and f_s.dtype == np.float32
    i, j, s = cgenreg.match_then_fuse(f_s, f_t)
    ri, rj, rs = res.correspondences
    np.testing.assert_array_equal(i, ri)
    np.testing.assert_array_equal(j, rj)
    np.testing.assert_array_equal(s, rs)
    est = cgenreg.sc2pcr(kp_s[i], kp_t[j], s)
    np.testing.assert_array_equal(est.target_from_source, res.target_from_source)
    np.testing.assert_array_equal(est.inliers, res.inliers)
    assert est.method == res.estimator and est.warning is None
    # the estimate is right: close to the ground truth
    err = np.linalg.norm(est.target_from_source[:3, 3] - gt[:3, 3])
    assert err < 0.3, err


def test_match_then_fuse_settings_and_image_branch_inputs():
    rng = np.random.default_rng(3)
    fs, ft = rng.random((40, 8), dtype=np.float32), rng.random((30, 8), dtype=np.float32)
    i, j, s = cgenreg.match_then_fuse(fs, ft)  # row NN: one per source row
    assert len(i) == 40 and sorted(i.tolist()) == list(range(40))
    ims, imt = rng.random((40, 5), dtype=np.float32), rng.random((30, 5), dtype=np.float32)
    mi, mj, _ = cgenreg.match_then_fuse(fs, ft, ims, imt)  # fused: mutual NN
    assert len(mi) <= 30 and len(set(mj.tolist())) == len(mj)
    ti, tj, ts = cgenreg.match_then_fuse(fs, ft, selection="topk", topk=7)
    assert len(ti) == 7 and np.all(np.diff(ts) <= 0)
    with pytest.raises(cgenreg.InvalidInput, match="source_img and target_img"):
        cgenreg.match_then_fuse(fs, ft, source_img=ims)


def test_load_bench_reads_a_cli_run(data_root, cli_binary, tmp_path):
    out = tmp_path / "run.json"
    args = [str(cli_binary), "bench", str(STAGED), "--split", "3DLoMatch",
            "--limit", "1", "--voxel", "0.05", "--json", str(out)]
    subprocess.run(args, check=True, capture_output=True, timeout=600)
    run = cgenreg.load_bench(out, as_frame=False)
    raw = json.loads(out.read_text())
    assert len(run["pairs"]) == 1 and run["pairs"][0]["id"] == raw["pairs"][0]["id"]
    assert run["params"] == raw["params"] and run["params"]["voxel"] == 0.05
    assert run["arrays"]["rre_deg"].dtype == np.float64
    assert close(run["arrays"]["rre_deg"][0], raw["pairs"][0]["rre_deg"])
    try:
        import pandas  # noqa: F401
    except ImportError:
        return
    df = cgenreg.load_bench(out)["pairs"]
    assert list(df["id"]) == [raw["pairs"][0]["id"]]


def _console_script() -> Path:
    p = Path(sys.executable).parent / "cgenreg"
    assert p.is_file(), "the cgenreg console script is installed with the package"
    return p


def test_console_script_runs_the_cli(data_root, tmp_path):
    d = data_root / "3dmatch-redkitchen" / "geotransformer-demo"
    out = subprocess.run(
        [str(_console_script()), "register", "--source", str(d / "src.npy"), "--target",
         str(d / "ref.npy"), "--gt", str(d / "gt.npy"), "--json"],
        check=True, capture_output=True, text=True, timeout=600,
    )
    r = json.loads(out.stdout)
    py = json.loads(cgenreg.register(d / "src.npy", d / "ref.npy", d / "gt.npy").to_json())
    assert close(r["target_from_source"], py["target_from_source"])
    bad = subprocess.run([str(_console_script()), "register", "--voxel", "-2"],
                         capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and "--voxel" in bad.stderr


def test_without_gui_the_inspector_is_the_native_binary(monkeypatch, capsys, tmp_path):
    """A wheel built without the GUI hands `cgenreg inspect` to a native binary, and says how
    to get one when there is none."""
    from cgenreg import _cli, inspector

    monkeypatch.setattr(cgenreg._cgenreg, "HAS_GUI", False)
    monkeypatch.delenv("CGENREG_BIN", raising=False)
    monkeypatch.setenv("PATH", str(tmp_path))  # nothing there
    assert _cli.main(["inspect", "--demo"]) == 1
    assert "cargo install --path ." in capsys.readouterr().err
    with pytest.raises(cgenreg.CgenregError, match="CGENREG_BIN"):
        inspector.inspector_command()
    monkeypatch.setenv("CGENREG_BIN", "/opt/cgenreg/bin/cgenreg")
    assert inspector.inspector_command() == ["/opt/cgenreg/bin/cgenreg"]
    assert _cli._wants_gui([]) and _cli._wants_gui(["inspect"]) and _cli._wants_gui(["screenshot"])
    assert not _cli._wants_gui(["register", "--help"]) and not _cli._wants_gui(["--version"])


def test_inspect_argument_vector_and_pair_manifest(data_root, tmp_path):
    """inspect() on arrays writes a one-pair manifest and starts the inspector with an argument
    vector; the manifest registers to the same result as the arrays."""
    src, ref, gt = _demo(data_root)
    log = tmp_path / "argv; $(touch pwned).json"  # a hostile file name reaches no shell
    recorder = tmp_path / "rec.py"
    recorder.write_text(
        "import json, sys\njson.dump(sys.argv[1:], open(sys.argv[1], 'w'))\n"
    )
    proc = cgenreg.inspect(
        source=src, target=ref, gt=gt, voxel=0.05, wait=True,
        command=[sys.executable, str(recorder), str(log)],
    )
    assert proc.returncode == 0
    argv = json.loads(log.read_text())
    assert argv[1] == "inspect" and argv[argv.index("--voxel") + 1] == "0.05"
    assert not (tmp_path / "pwned").exists()
    manifest, pair = argv[argv.index("--manifest") + 1], argv[argv.index("--pair") + 1]
    assert not os.path.exists(manifest), "the temporary pair is removed after wait=True"
    # the same manifest, written again, registers like the arrays
    folder = tmp_path / "pair"
    folder.mkdir()
    from cgenreg.inspector import _write_pair

    m = _write_pair(str(folder), src, ref, gt)
    a = cgenreg.register(src, ref, gt, voxel=0.05)
    b = cgenreg.register_pair(m, pair, voxel=0.05)
    np.testing.assert_array_equal(a.target_from_source, b.target_from_source)
    assert a.rre_deg == b.rre_deg


def test_screenshot_through_the_native_binary_draws_what_register_computes(
    data_root, cli_binary, tmp_path, monkeypatch
):
    """`cgenreg.screenshot` on two arrays runs the real GUI binary headless (no window, no
    display): it writes the PNG at the size asked, and the result the picture shows equals
    `cgenreg.register` on the same arrays and settings. A failure is an exception carrying the
    program's message, and a file that is not a picture is never replaced."""
    import struct

    monkeypatch.setenv("CGENREG_BIN", str(cli_binary))  # as a user without the GUI wheel
    src, ref, gt = _demo(data_root)
    out = tmp_path / "pair.png"
    shown = cgenreg.screenshot(
        source=src, target=ref, gt=gt, out=out, width=640, height=400,
        result_json=tmp_path / "shown.json", voxel=0.05,
    )
    head = out.read_bytes()[:24]
    assert head[:8] == b"\x89PNG\r\n\x1a\n"
    assert struct.unpack(">II", head[16:24]) == (640, 400)
    py = json.loads(cgenreg.register(src, ref, gt, voxel=0.05).to_json())
    assert close(shown["target_from_source"], py["target_from_source"])
    assert shown["metrics"]["rre_deg"] == pytest.approx(py["metrics"]["rre_deg"], rel=1e-9)
    assert shown["n_correspondences"] == py["n_correspondences"]
    notes = tmp_path / "notes.png"  # not a picture: never replaced without force
    notes.write_text("my notes")
    with pytest.raises(cgenreg.CgenregError, match="notes.png"):
        cgenreg.screenshot(source=src, target=ref, out=notes, voxel=0.05)
    assert notes.read_text() == "my notes"
    with pytest.raises(cgenreg.CgenregError, match="--voxel"):
        cgenreg.screenshot(
            source=src, target=ref, out=tmp_path / "bad.png", voxel=-1, command=[str(cli_binary)]
        )
