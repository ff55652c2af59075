"""The package's registrations equal the command line's on the staged real pairs."""

from __future__ import annotations

import json
import threading
import time

import numpy as np
import pytest

import cgenreg
from conftest import STAGED, close, run_cli, without_timings

# Two 3DMatch pairs (one of full-resolution fragments, one of downsampled ones) and a
# 3DLoMatch pair of the staged redkitchen manifest.
PAIRS = ["redkitchen/0-1", "redkitchen/5-6", "redkitchen/21-34"]


@pytest.mark.parametrize("pair", PAIRS)
def test_register_pair_equals_cli(data_root, cli_binary, pair):
    cli = run_cli(
        cli_binary, ["register", "--manifest", str(STAGED), "--pair", pair, "--no-cache"]
    )
    res = cgenreg.register_pair(STAGED, pair, no_cache=True)
    py = json.loads(res.to_json())
    assert close(without_timings(py), without_timings(cli)), (py, cli)
    # the attributes are the JSON's numbers
    np.testing.assert_array_equal(res.target_from_source, np.array(py["target_from_source"]))
    assert res.rre_deg == py["metrics"]["rre_deg"] and res.rte_m == py["metrics"]["rte_m"]
    src, tgt, scores = res.correspondences
    assert len(src) == len(tgt) == len(scores) == cli["n_correspondences"]
    assert len(res.inliers) == cli["n_inliers"]
    assert src.max() < cli["n_source_keypoints"] and tgt.max() < cli["n_target_keypoints"]
    assert np.all(np.diff(scores) <= 0), "correspondences are sorted by score, best first"
    assert [t[0] for t in res.timings] == [t["stage"] for t in cli["timings"]]


def _demo_files(data_root):
    d = data_root / "3dmatch-redkitchen" / "geotransformer-demo"
    return d / "src.npy", d / "ref.npy", d / "gt.npy"


def test_files_and_arrays_equal_cli(data_root, cli_binary):
    """`cgenreg register --source --target --gt` = register(files) = register(arrays)."""
    src, ref, gt = _demo_files(data_root)
    cli = run_cli(
        cli_binary,
        ["register", "--source", str(src), "--target", str(ref), "--gt", str(gt), "--voxel", "0.05"],
    )
    from_files = cgenreg.register(src, ref, gt, voxel=0.05)
    assert close(without_timings(json.loads(from_files.to_json())), without_timings(cli))
    # arrays: float64 arrays as np.load gives them, the GT as an array
    from_arrays = cgenreg.register(np.load(src), np.load(ref), np.load(gt), voxel=0.05)
    a = json.loads(from_arrays.to_json())
    for key in ("target_from_source", "metrics", "n_correspondences", "n_inliers", "estimator"):
        assert close(a[key], cli[key]), key
    assert from_arrays.success is True and from_arrays.rre_deg < 15.0


def test_settings_are_the_cli_defaults():
    s = cgenreg.settings()
    assert s["voxel"] == 0.05 and s["image"] is None
    assert s["fusion"]["selection"] == "RowNn" or "Row" in json.dumps(s["fusion"]["selection"])
    img = cgenreg.settings(wfm="builtin", k=3, tau_img=0.05)
    assert img["image"]["k"] == 3 and img["image"]["backend"] == {"kind": "builtin"}
    assert "0.05" in json.dumps(img["fusion"]["calibration_img"])
    # two branches: the fused default selection (mutual NN), as the CLI
    assert json.dumps(img["fusion"]["selection"]) != json.dumps(s["fusion"]["selection"])


def test_result_params_are_the_run_settings(data_root):
    src, ref, gt = _demo_files(data_root)
    res = cgenreg.register(src, ref, gt, voxel=0.1, selection="mutual")
    p = json.loads(res.params_json())
    assert p == cgenreg.settings(voxel=0.1, selection="mutual")


def test_gil_is_released_during_registration(data_root):
    """Another Python thread runs while a registration computes."""
    src, ref, gt = _demo_files(data_root)
    a, b = np.load(src), np.load(ref)
    done = []
    t = threading.Thread(target=lambda: done.append(cgenreg.register(a, b, voxel=0.025)))
    ticks = 0
    t0 = time.perf_counter()
    t.start()
    while t.is_alive():
        ticks += 1
        time.sleep(0.001)
    elapsed = time.perf_counter() - t0
    t.join()
    assert done and elapsed > 0.05
    # with the GIL held this loop could not run while the extension computes
    assert ticks > 0.3 * elapsed / 0.001 * 0.1, (ticks, elapsed)


def test_image_branch_pair_equals_cli(data_root, cli_binary, tmp_path):
    """The full method (built-in frames + ALIKE-t, the default visibility fusion) on the bundled demo
    pair: the package gives the command line's result, with the image branch's provenance."""
    demo = STAGED.parents[1] / "demo" / "demo.toml"
    opts = ["--wfm", "builtin", "--vfm", "alike", "--frames", "8", "--margin", "1", "--k", "2",
            "--voxel", "0.05", "--cache-dir", str(tmp_path / "cache")]
    cli = run_cli(cli_binary, ["register", "--manifest", str(demo), "--pair", "synth-room/0-1"] + opts)
    res = cgenreg.register_pair(demo, "synth-room/0-1", wfm="builtin", vfm="alike", frames=8,
                                margin=1, k=2, voxel=0.05, cache_dir=str(tmp_path / "cache"))
    py = json.loads(res.to_json())
    for key in ("target_from_source", "metrics", "n_correspondences", "n_inliers", "image_branch"):
        assert close(py[key], cli[key]), key
    assert "fusion: visibility" in py["image_branch"] and "builtin" in py["image_branch"]
