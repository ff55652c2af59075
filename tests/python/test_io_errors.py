"""Readers round trips, errors as exceptions with the library's messages, and the arrays the
package promises not to copy."""

from __future__ import annotations

import json

import numpy as np
import pytest

import cgenreg
from cgenreg import FileError, FormatError, InvalidInput


def _cloud(n=500, seed=1):
    rng = np.random.default_rng(seed)
    return (rng.random((n, 3)) * 4.0 - 2.0).astype(np.float32)


@pytest.mark.parametrize("ext", ["ply", "npy", "xyz", "txt", "pts"])
def test_write_read_round_trip(tmp_path, ext):
    pts = _cloud()
    p = tmp_path / ("c." + ext)
    cgenreg.write_cloud(p, pts)
    back = cgenreg.read_cloud(p)
    assert back.dtype == np.float64 and back.shape == pts.shape
    if ext in ("ply", "npy"):  # binary float32: exact
        np.testing.assert_array_equal(back, pts.astype(np.float64))
    else:  # text: as written by the library's text writer
        np.testing.assert_allclose(back, pts, rtol=0, atol=1e-5)


def test_numpy_files_round_trip(tmp_path):
    pts = _cloud().astype(np.float64)
    np.save(tmp_path / "a.npy", pts)
    np.testing.assert_array_equal(cgenreg.read_cloud(tmp_path / "a.npy"), pts.astype(np.float32))


def test_kitti_bin_intensity_and_ply_colours(tmp_path):
    pts = _cloud(300)
    inten = np.linspace(0, 1, 300, dtype=np.float32)
    np.column_stack([pts, inten]).astype(np.float32).tofile(tmp_path / "scan.bin")
    p, ex = cgenreg.read_cloud(tmp_path / "scan.bin", extras=True)
    np.testing.assert_array_equal(p, pts)
    np.testing.assert_array_equal(ex["intensity"], inten)
    assert ex["colors"] is None
    # an ASCII PLY with colours
    rgb = (np.arange(300 * 3) % 256).reshape(300, 3).astype(np.uint8)
    with open(tmp_path / "c.ply", "w") as f:
        f.write(
            "ply\nformat ascii 1.0\nelement vertex 300\nproperty float x\nproperty float y\n"
            "property float z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\n"
            "end_header\n"
        )
        for q, c in zip(pts, rgb):
            f.write("%r %r %r %d %d %d\n" % (float(q[0]), float(q[1]), float(q[2]), *c))
    p, ex = cgenreg.read_cloud(tmp_path / "c.ply", extras=True)
    np.testing.assert_array_equal(p, pts)
    np.testing.assert_array_equal(ex["colors"], rgb)
    # an ASCII PCD
    with open(tmp_path / "c.pcd", "w") as f:
        f.write(
            "VERSION .7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 300\nHEIGHT 1\n"
            "VIEWPOINT 0 0 0 1 0 0 0\nPOINTS 300\nDATA ascii\n"
        )
        for q in pts:
            f.write("%r %r %r\n" % (float(q[0]), float(q[1]), float(q[2])))
    np.testing.assert_array_equal(cgenreg.read_cloud(tmp_path / "c.pcd"), pts)


def test_staged_reader_formats_agree(data_root):
    """Fragment 6 of redkitchen staged as .npy and the same fragment read through .pth."""
    d = data_root / "3dmatch-redkitchen"
    a = cgenreg.read_cloud(d / "geotransformer-demo" / "src.npy")
    assert a.ndim == 2 and a.shape[1] == 3 and len(a) > 1000
    kitti = cgenreg.read_cloud(data_root / "kitti07-lidar" / "keyframe-0.bin")
    assert kitti.shape[1] == 3 and np.isfinite(kitti).all()


def test_missing_file_is_a_file_error(tmp_path):
    missing = tmp_path / "nope.ply"
    with pytest.raises(FileError) as e:
        cgenreg.read_cloud(missing)
    assert str(missing) in str(e.value) and e.value.path == str(missing)
    assert isinstance(e.value, OSError)


def test_bad_content_is_a_format_error_naming_file_and_field(tmp_path):
    p = tmp_path / "bad.ply"
    p.write_text("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nend_header\n1\n2\n")
    with pytest.raises(FormatError) as e:
        cgenreg.read_cloud(p)
    assert e.value.path == str(p) and str(p) in str(e.value)
    assert e.value.field and e.value.expected
    with pytest.raises(FormatError) as e:
        cgenreg.read_cloud(tmp_path / "x.obj")
    assert e.value.field == "extension" and ".ply" in e.value.expected


def test_bad_option_is_invalid_input_with_the_cli_message():
    with pytest.raises(InvalidInput) as e:
        cgenreg.settings(voxel=-1.0)
    assert "--voxel" in str(e.value) and "positive" in str(e.value)
    with pytest.raises(InvalidInput) as e:
        cgenreg.settings(no_such_setting=3)
    assert "--no-such-setting" in str(e.value)
    with pytest.raises(InvalidInput) as e:
        cgenreg.settings(selection="best")
    assert "best" in str(e.value) and "mutual" in str(e.value)
    with pytest.raises(InvalidInput) as e:
        cgenreg.settings(wfm="cached")
    assert "--wfm-dir" in str(e.value)


def test_bad_arrays_are_invalid_input():
    with pytest.raises(InvalidInput, match=r"source.*\(N, 3\)"):
        cgenreg.register(np.zeros((10, 2)), np.zeros((10, 3)))
    bad = _cloud(50)
    bad[7, 1] = np.nan
    with pytest.raises(InvalidInput, match="point 7"):
        cgenreg.register(bad, _cloud(50))
    with pytest.raises(InvalidInput, match=r"gt.*rigid"):
        cgenreg.register(_cloud(50), _cloud(50), gt=np.full((4, 4), 2.0))
    with pytest.raises(InvalidInput, match="both as files or both as arrays"):
        cgenreg.register("a.ply", _cloud(50))
    with pytest.raises(InvalidInput, match="src_xyz has 5 points but tgt_xyz has 4"):
        cgenreg.sc2pcr(_cloud(5), _cloud(4))
    with pytest.raises(InvalidInput, match="voxel"):
        cgenreg.fpfh(_cloud(50), 0.0)


def test_degenerate_estimate_is_invalid_input():
    p = np.zeros((2, 3), dtype=np.float32)
    with pytest.raises(InvalidInput, match="degenerate"):
        cgenreg.sc2pcr(p, p)


def test_load_bench_errors_name_the_field(tmp_path):
    p = tmp_path / "run.json"
    p.write_text(json.dumps({"params": {}}))
    with pytest.raises(FormatError) as e:
        cgenreg.load_bench(p)
    assert e.value.field == "pairs" and e.value.path == str(p)
    p.write_text("{not json")
    with pytest.raises(FormatError):
        cgenreg.load_bench(p)


def test_no_copies(data_root):
    """Arrays the library computes are handed to NumPy without a copy (NumPy's array does not
    own its data: the Rust buffer does); float32 C-contiguous inputs are passed on as they are."""
    d = data_root / "3dmatch-redkitchen" / "geotransformer-demo"
    src = cgenreg.read_cloud(d / "src.npy")
    kp, feats = cgenreg.fpfh(src, 0.05)
    for a in (src, kp, feats):
        assert not a.flags.owndata and a.base is not None, "a NumPy-side copy"
        assert a.flags.c_contiguous
    res = cgenreg.register(src, cgenreg.read_cloud(d / "ref.npy"), voxel=0.05)
    c1, c2 = res.correspondences, res.correspondences
    for x, y in zip(c1, c2):
        assert x is y and not x.flags.owndata  # made once, from the result's buffer
    assert res.inliers is res.inliers and res.target_from_source is res.target_from_source
    # inputs: a float32 C-contiguous array goes to the extension as is (the extension then
    # reads it in place); other layouts are converted once
    a32 = np.ascontiguousarray(kp)
    assert cgenreg._f32(a32, "x", 3) is a32
    assert not np.shares_memory(cgenreg._f32(src, "x", 3), src)  # float64: converted
    fortran = np.asfortranarray(kp)
    assert cgenreg._f32(fortran, "x", 3).flags.c_contiguous
