"""Checks shared by models/export_disk.py and models/export_alike.py (dense per-pixel VFMs).

- `compare_onnx`: ONNX Runtime against the torch model on real 7-Scenes redkitchen frames and on
  random inputs, max |difference| of the raw and of the L2-normalised descriptors.
- `reprojection_check`: frames a -> b of redkitchen with ground-truth poses and depth: for query
  pixels of frame a with valid depth, the dense nearest neighbour (cosine) over every pixel of frame
  b, and the distance from the ground-truth reprojection. Two query sets: the model's own keypoints
  (when it has a detector; what shared/models/MANIFEST.md reports) and a regular grid (what
  tests/it/vfm_dense.rs measures in Rust, no detector needed).
- `write_fixture`: descriptors of frame 0 at a few pixels, for tests/it/vfm_dense.rs.

Data conventions (shared/data/7scenes-redkitchen-rgbd/MANIFEST.md): depth PNG in mm, 0 (and
65535) invalid; pose files are world_from_camera; K is fx = fy = 585, cx = 320, cy = 240. Colour
and depth come from different Kinect cameras and are not registered, so the colour pixel is taken
as the depth pixel, as the MANIFEST's measurement does.
"""
import os

import numpy as np
import torch
import torch.nn.functional as F

FX, FY, CX, CY = 585.0, 585.0, 320.0, 240.0


def data_dir():
    root = os.environ.get("CGENREG_DATA") or os.path.join(os.path.dirname(__file__), "..", "..", "shared", "data")
    d = os.path.join(root, "7scenes-redkitchen-rgbd")
    if not os.path.isdir(d):
        raise SystemExit(f"{d}: redkitchen frames not found (set CGENREG_DATA)")
    return d


def load_rgb(i):
    from PIL import Image

    img = Image.open(os.path.join(data_dir(), f"frame-{i:06d}.color.jpg")).convert("RGB")
    return torch.from_numpy(np.asarray(img).copy()).permute(2, 0, 1).float()[None] / 255.0


def load_depth(i):
    from PIL import Image

    d = np.asarray(Image.open(os.path.join(data_dir(), f"frame-{i:06d}.depth.png"))).astype(np.float64)
    d[d == 65535] = 0
    return d / 1000.0


def load_pose(i):
    return np.loadtxt(os.path.join(data_dir(), f"frame-{i:06d}.pose.txt"))


def pad_to(x, m):
    """Zero-pad bottom/right to a multiple of m (what kornia DISK and ALIKE do)."""
    h, w = x.shape[-2:]
    return F.pad(x, (0, (-w) % m, 0, (-h) % m), value=0.0)


def declare_multiple(model, multiple):
    """Name the H and W axes of every graph input and output `m*h<m>` / `m*w<m>` (an ONNX dim_param
    expression). ONNX Runtime reads them as plain names; tract, the pure-Rust fallback, parses them
    and so knows that H and W are multiples of `m`, without which it cannot prove that an upsampled
    (H/16)*2 equals the skip connection's H/8 and refuses the graph at the first Concat."""
    for vi in list(model.graph.input) + list(model.graph.output):
        d = vi.type.tensor_type.shape.dim
        d[2].dim_param = f"{multiple}*h{multiple}"
        d[3].dim_param = f"{multiple}*w{multiple}"


def compare_tract(path, multiple, label):
    """tract (Python bindings of the same tract version as cgenreg's fallback), when installed,
    against ONNX Runtime on one random input."""
    try:
        import tract
    except ImportError:
        print(f"{label}: tract not installed here, tract check skipped (pip install tract==0.23.9)")
        return None
    import onnxruntime as ort

    h, w = 7 * multiple, 10 * multiple
    x = np.random.default_rng(0).random((1, 3, h, w)).astype(np.float32)
    a = tract.onnx().load(path).into_model().into_runnable().run([x])[0].to_numpy()
    b = ort.InferenceSession(path, providers=["CPUExecutionProvider"]).run(["descriptors"], {"image": x})[0]
    diff = float(np.abs(a - b).max())
    print(f"{label}: max |tract - ONNX Runtime| raw at {w}x{h}: {diff:.2e}")
    return diff


def compare_onnx(sess, torch_desc, multiple, label):
    """torch_desc(x) -> raw descriptors (1, D, H, W) for an input already padded to `multiple`."""
    worst_raw, worst_unit = 0.0, 0.0
    cases = [("frame 0", load_rgb(0)), ("frame 20", load_rgb(20))]
    cases.append(("frame 0 at 960x704", F.interpolate(load_rgb(0), size=(704, 960), mode="bilinear", align_corners=False)))
    g = torch.Generator().manual_seed(0)
    cases += [(f"random {w}x{h}", torch.rand(1, 3, h, w, generator=g)) for (h, w) in [(480, 640), (704, 960), (224, 320)]]
    for name, x in cases:
        x = pad_to(x, multiple)
        with torch.no_grad():
            want = torch_desc(x)
        got = torch.from_numpy(sess.run(["descriptors"], {"image": x.numpy()})[0])
        raw = float((got - want).abs().max())
        unit = float((F.normalize(got, dim=1) - F.normalize(want, dim=1)).abs().max())
        cos = float(F.cosine_similarity(got, want, dim=1).min())
        worst_raw, worst_unit = max(worst_raw, raw), max(worst_unit, unit)
        print(
            f"  {label} {name} {tuple(x.shape[2:])}: max |ONNX - torch| raw {raw:.2e} (max |torch| "
            f"{float(want.abs().max()):.1f}), L2-normalised {unit:.2e}, min cosine {cos:.7f}"
        )
    print(f"{label}: max |ONNX - torch| over all inputs: raw {worst_raw:.2e}, L2-normalised {worst_unit:.2e}")
    return worst_raw, worst_unit


def reproject(a, b, pts):
    """Pixels (u, v) of frame a with depth -> (pixels in b, in-view mask)."""
    depth = load_depth(a)
    u, v = pts[:, 0], pts[:, 1]
    z = depth[v, u]
    ok = z > 0
    xa = np.stack([(u - CX) * z / FX, (v - CY) * z / FY, z, np.ones_like(z)])
    b_from_a = np.linalg.inv(load_pose(b)) @ load_pose(a)
    xb = b_from_a @ xa
    ub = FX * xb[0] / xb[2] + CX
    vb = FY * xb[1] / xb[2] + CY
    ok &= (xb[2] > 0) & (ub >= 0) & (ub <= 639) & (vb >= 0) & (vb <= 479)
    return np.stack([ub, vb], 1), ok


def grid_queries(step=16, offset=8):
    """The query pixels of tests/it/vfm_dense.rs: every `step` px from `offset`, row-major."""
    us, vs = np.meshgrid(np.arange(offset, 640, step), np.arange(offset, 480, step))
    return np.stack([us.ravel(), vs.ravel()], 1)


def nn_errors(desc_a, desc_b, pts_a, want_b):
    """Dense NN of each query descriptor of a over all pixels of b (unit descriptors, (D, H, W))."""
    d, h, w = desc_b.shape
    qa = desc_a[:, pts_a[:, 1], pts_a[:, 0]].T  # (N, D)
    flat = desc_b.reshape(d, -1)
    idx = []
    for i in range(0, len(qa), 256):
        idx.append((qa[i : i + 256] @ flat).argmax(1))
    idx = torch.cat(idx).numpy()
    got = np.stack([idx % w, idx // w], 1).astype(np.float64)
    return np.linalg.norm(got - want_b, axis=1)


def reprojection_check(dense, a=0, b=20, keypoints=None, label="model"):
    """dense(rgb (1,3,480,640)) -> unit descriptors (D, 480, 640). Prints and returns the
    within-5-px percentages (keypoints, grid)."""
    da, db = dense(load_rgb(a)), dense(load_rgb(b))
    out = {}
    sets = [("grid 16 px", grid_queries())]
    if keypoints is not None:
        sets.insert(0, ("keypoints", keypoints(load_rgb(a))))
    for name, pts in sets:
        pts = pts.astype(np.int64)
        want, ok = reproject(a, b, pts)
        err = nn_errors(da, db, pts[ok], want[ok])
        p5 = 100.0 * float((err <= 5.0).mean())
        print(
            f"{label} frames {a} -> {b}, {name}: {ok.sum()} queries with depth in view, "
            f"{p5:.1f} % within 5 px, {100.0 * float((err <= 10.0).mean()):.1f} % within 10 px, "
            f"median {np.median(err):.2f} px"
        )
        out[name] = p5
    return out


def write_fixture(path, unit_desc, pts):
    """(N, 2 + D) float32: u, v, then the unit descriptor at that pixel of frame 0."""
    rows = np.concatenate([pts.astype(np.float32), unit_desc[:, pts[:, 1], pts[:, 0]].T.numpy()], 1)
    np.save(path, rows.astype(np.float32))
    print(f"{path}: {rows.shape[0]} pixels x {rows.shape[1] - 2} dims, {os.path.getsize(path)} bytes")


FIXTURE_PIXELS = np.array([[8, 8], [100, 50], [320, 240], [631, 471], [200, 400], [500, 120], [47, 333], [600, 20]])
