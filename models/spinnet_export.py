#!/usr/bin/env python3
"""SpinNet (Ao et al., CVPR 2021) for cgenreg: export the network after the patch grouping to
ONNX, check ONNX Runtime against torch on real patches, and dump the authors' grouped patches for
the Rust port's parity test. Run through models/spinnet_export.sh (a scratch venv under target/).

    spinnet_export.py [--out-dir target/spinnet] [--keypoints 4] [--skip-export]

Reads (never copies) the authors' code (`--code`, default ../shared/third_party/qingyonghu-spinnet),
their checkpoints (`--weights`, default ../shared/models/spinnet) and the data (`--data`, default
$CGENREG_DATA or ../shared/data). Writes under --out-dir only:

    spinnet-3dmatch.onnx, spinnet-kitti.onnx   the network after the grouping (research-only
                                               weights: never commit these files)
    parity-3dmatch.npz, parity-kitti.npz       keypoints, patches, local (patch after the local
                                               reference frame), grouped, desc_torch, desc_onnx
    report.json                                versions, hashes, the ONNX-vs-torch differences

Graph contract (read by src/features/spinnet/model.rs):
    input  grouped     float32 (B, rad_n*ele_n*azi_n, 30, 3): the 30 points sampled in each
                       spherical voxel, relative to the voxel centre, rotated by -azimuth
                       (the authors' `var_to_invar` output); B dynamic
    output descriptor  float32 (B, 32), not normalised

The authors' forward runs on CUDA (`pointnet2_ops.ball_query`, `.cuda()`) and old torch
(`torch.symeig`). This script changes only that plumbing: `ball_query` and `grouping_operation`
are ported to CPU torch (the kernel's semantics: the first `nsample` points with squared
distance < r^2 in index order, f32, the rest filled with the first; no point: index 0),
`.cuda()` is the identity and `symeig` is `linalg.eigh` (same ascending order). The grouped tensor
and the descriptor are computed by the authors' own `Descriptor_Net.forward`, and the
step-by-step copy used for the intermediates is asserted equal to it.
"""
import argparse
import hashlib
import json
import os
import sys
import time
import types

import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

# name -> (checkpoint, Descriptor_Net arguments, protocol)
MODELS = {
    "3dmatch": ("3DMatch_best.pkl", (0.30, 9, 80, 40, 0.04, 30, "3DMatch")),
    "kitti": ("KITTI_best.pkl", (2.0, 9, 60, 30, 0.3, 30, "KITTI")),
}
POINTS_PER_PATCH = 2048


def ball_query(radius, nsample, xyz, new_xyz):
    """pointnet2_ops.ball_query on CPU: (B, N, 3), (B, S, 3) -> (B, S, nsample) int64."""
    r2 = torch.tensor(radius, dtype=torch.float32) * torch.tensor(radius, dtype=torch.float32)
    B, S, _ = new_xyz.shape
    out = torch.zeros(B, S, nsample, dtype=torch.int64)
    for b in range(B):
        for s0 in range(0, S, 2048):
            q = new_xyz[b, s0:s0 + 2048]
            p = xyz[b]
            dx = q[:, None, 0] - p[None, :, 0]
            dy = q[:, None, 1] - p[None, :, 1]
            dz = q[:, None, 2] - p[None, :, 2]
            d2 = dx * dx + dy * dy
            d2 = d2 + dz * dz
            mask = d2 < r2
            del dx, dy, dz, d2
            rank = torch.cumsum(mask.to(torch.int32), dim=1) - 1
            valid = mask & (rank < nsample)
            first = torch.where(mask.any(dim=1), mask.to(torch.int8).argmax(dim=1), 0)
            idx = first[:, None].repeat(1, nsample)
            rows, cols = valid.nonzero(as_tuple=True)
            idx[rows, rank[rows, cols].long()] = cols
            out[b, s0:s0 + q.shape[0]] = idx
    return out.int()


def grouping_operation(features, idx):
    """pointnet2_ops.grouping_operation on CPU: (B, C, N), (B, S, ns) -> (B, C, S, ns)."""
    B, C, N = features.shape
    _, S, ns = idx.shape
    flat = idx.long().reshape(B, 1, S * ns).expand(B, C, S * ns)
    return torch.gather(features, 2, flat).reshape(B, C, S, ns)


def install_cpu_shims():
    pn2 = types.ModuleType("pointnet2_ops")
    utils = types.ModuleType("pointnet2_ops.pointnet2_utils")
    utils.ball_query = ball_query
    utils.grouping_operation = grouping_operation
    pn2.pointnet2_utils = utils
    sys.modules["pointnet2_ops"] = pn2
    sys.modules["pointnet2_ops.pointnet2_utils"] = utils
    # imported by script/common.py, unused by the descriptor
    sys.modules.setdefault("open3d", types.ModuleType("open3d"))
    sk = types.ModuleType("sklearn")
    skn = types.ModuleType("sklearn.neighbors")
    skn.KDTree = None
    sk.neighbors = skn
    sys.modules.setdefault("sklearn", sk)
    sys.modules.setdefault("sklearn.neighbors", skn)
    torch.Tensor.cuda = lambda self, *a, **k: self
    torch.symeig = lambda a, eigenvectors=True: torch.linalg.eigh(a)


def load_model(code, weights, name):
    pkl, args = MODELS[name]
    if code not in sys.path:
        sys.path.insert(0, code)
    import network.SpinNet as sn  # noqa: E402  (the authors' module)

    model = sn.Descriptor_Net(*args)
    state = torch.load(os.path.join(weights, pkl), map_location="cpu", weights_only=True)
    state = {k[len("module."):] if k.startswith("module.") else k: v for k, v in state.items()}
    model.load_state_dict(state, strict=True)
    model.eval()
    return model


class AfterGrouping(nn.Module):
    """The authors' forward from `new_points = var_to_invar(...)` on, with their layers."""

    def __init__(self, net):
        super().__init__()
        self.net = net

    def forward(self, grouped):
        n = self.net
        x = grouped.permute(0, 3, 1, 2)
        x = n.activation(n.bn_xyz_raising(n.xyz_raising(x)))
        x = F.max_pool2d(x, kernel_size=(1, n.voxel_sample)).squeeze(3)
        x = x.view(x.shape[0], x.shape[1], n.rad_n, n.ele_n, n.azi_n)
        x = n.conv_net(x)
        # the authors' max_pool2d over the whole (H, W) map, written as a max over both axes
        # (the same values; a kernel size read from the shape does not export)
        return torch.amax(x, dim=(2, 3))


def intermediates(net, patches):
    """The authors' forward up to the grouping, step by step: (local, grouped)."""
    import script.common as cm

    inp = patches
    center = inp[:, -1, :].unsqueeze(1)
    delta_x = inp[:, :, 0:3] - center[:, :, 0:3]
    if net.dataset == "3DMatch":
        z_axis = cm.cal_Z_axis(delta_x, ref_point=inp[:, -1, :3])
        z_axis = cm.l2_norm(z_axis, axis=1)
        R = cm.RodsRotatFormula(z_axis, torch.FloatTensor([0, 0, 1]).unsqueeze(0).repeat(z_axis.shape[0], 1))
        delta_x = torch.matmul(delta_x, R)
    s2 = torch.FloatTensor(cm.get_voxel_coordinate(radius=net.des_r, rad_n=net.rad_n, azi_n=net.azi_n,
                                                   ele_n=net.ele_n))
    pts_xyz = s2.view(1, -1, 3).repeat([delta_x.shape[0], 1, 1])
    new_points = cm.sphere_query(delta_x, pts_xyz, radius=net.voxel_r, nsample=net.voxel_sample)
    new_points = new_points - pts_xyz.unsqueeze(2).repeat([1, 1, net.voxel_sample, 1])
    new_points = cm.var_to_invar(new_points, net.rad_n, net.azi_n, net.ele_n)
    return delta_x, new_points


def read_ply_xyz(path):
    """Binary little-endian PLY with float32 x, y, z vertices (the staged redkitchen fragments)."""
    with open(path, "rb") as f:
        header = b""
        while not header.endswith(b"end_header\n"):
            line = f.readline()
            if not line:
                raise ValueError(f"{path}: no end_header")
            header += line
        text = header.decode("ascii")
        n = int([l for l in text.splitlines() if l.startswith("element vertex")][0].split()[2])
        props = [l.split()[2] for l in text.splitlines() if l.startswith("property")]
        if "binary_little_endian" not in text or props[:3] != ["x", "y", "z"] or len(props) != 3:
            raise ValueError(f"{path}: expected binary_little_endian float x y z only, got {props}")
        return np.frombuffer(f.read(n * 12), dtype="<f4").reshape(n, 3).copy()


def patches_3dmatch(pts, keypts, rng, vicinity=0.30, n=POINTS_PER_PATCH):
    """ThreeDMatch/Test/preparation.py `build_patch_input` (brute-force radius search)."""
    out = np.zeros([len(keypts), n, 3], dtype=np.float32)
    for i, k in enumerate(keypts):
        d2 = ((pts - k) ** 2).sum(1)
        neigh = pts[np.nonzero(d2 <= vicinity * vicinity)[0]]
        if neigh.shape[0] >= n:
            neigh = neigh[rng.choice(range(neigh.shape[0]), n, replace=False)]
        else:
            fix = np.arange(neigh.shape[0])
            while neigh.shape[0] + fix.shape[0] < n:
                fix = np.concatenate((fix, np.arange(neigh.shape[0])))
            rnd = rng.choice(neigh.shape[0], n - fix.shape[0], replace=False)
            neigh = neigh[np.concatenate((fix, rnd))]
        neigh = neigh.copy()
        neigh[-1] = k
        out[i] = neigh
    return out


def patches_kitti(pts, keypts, vicinity=2.0, n=POINTS_PER_PATCH):
    """KITTI/Test/test_kitti.py `select_patches`: ball query on the (shuffled) scan, the last
    point and the padding replaced by the keypoint."""
    p = torch.from_numpy(pts).unsqueeze(0)
    q = torch.from_numpy(keypts).unsqueeze(0)
    idx = ball_query(vicinity, n, p, q)
    new_points = grouping_operation(p.transpose(1, 2).contiguous(), idx).permute(0, 2, 3, 1)
    mask = idx[:, :, 0].unsqueeze(2).repeat(1, 1, n)
    mask = (idx == mask).float()
    mask[:, :, 0] = 0
    mask[:, :, n - 1] = 1
    mask = mask.unsqueeze(3).repeat(1, 1, 1, 3)
    new_pts = q.unsqueeze(2).repeat(1, 1, n, 1)
    return (new_points * (1 - mask) + new_pts * mask).squeeze(0).numpy().astype(np.float32)


def sha256(path):
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--code", default=os.path.join(ROOT, "..", "shared", "third_party", "qingyonghu-spinnet"))
    ap.add_argument("--weights", default=os.path.join(ROOT, "..", "shared", "models", "spinnet"))
    ap.add_argument("--data", default=os.environ.get("CGENREG_DATA", os.path.join(ROOT, "..", "shared", "data")))
    ap.add_argument("--out-dir", default=os.path.join(ROOT, "target", "spinnet"))
    ap.add_argument("--keypoints", type=int, default=4, help="keypoints per parity dump (not 3: "
                    "the authors' torch.cross(a, b) without dim picks the batch axis when B == 3)")
    ap.add_argument("--models", default="3dmatch,kitti")
    ap.add_argument("--skip-export", action="store_true")
    a = ap.parse_args()
    if a.keypoints == 3 or a.keypoints < 1:
        ap.error("--keypoints must be >= 1 and not 3")
    torch.set_num_threads(max(1, min(2, os.cpu_count() or 1)))
    install_cpu_shims()
    os.makedirs(a.out_dir, exist_ok=True)
    import onnxruntime as ort

    report = {"torch": torch.__version__, "onnxruntime": ort.__version__, "models": {}}
    clouds = {
        "3dmatch": ("3dmatch-redkitchen/teaser-plusplus/cloud_bin_0.ply",
                    lambda p: read_ply_xyz(p)),
        "kitti": ("kitti07-lidar/keyframe-0.bin",
                  lambda p: np.fromfile(p, dtype="<f4").reshape(-1, 3).copy()),
    }
    for name in a.models.split(","):
        t0 = time.time()
        net = load_model(a.code, a.weights, name)
        rel, reader = clouds[name]
        pts = reader(os.path.join(a.data, rel))
        rng = np.random.RandomState(0)
        # keypoints: evenly spaced indices of the cloud as stored (fixed, reproducible)
        kidx = np.linspace(0, len(pts) - 1, a.keypoints + 2).astype(np.int64)[1:-1]
        keypts = pts[kidx]
        if name == "3dmatch":
            patches = patches_3dmatch(pts, keypts, rng)
        else:
            shuffled = pts[rng.permutation(len(pts))]
            patches = patches_kitti(shuffled, keypts)
        x = torch.from_numpy(patches)
        with torch.no_grad():
            desc_authors = net(x).reshape(len(keypts), -1).numpy()
            local, grouped = intermediates(net, x)
            desc_torch = AfterGrouping(net)(grouped).numpy()
        step_diff = float(np.abs(desc_authors - desc_torch).max())
        assert step_diff == 0.0, f"step-by-step forward differs from the authors' by {step_diff}"
        onnx_path = os.path.join(a.out_dir, f"spinnet-{name}.onnx")
        if not a.skip_export:
            dummy = grouped[:2].clone()
            torch.onnx.export(AfterGrouping(net), (dummy,), onnx_path, input_names=["grouped"],
                              output_names=["descriptor"], opset_version=17, dynamo=False,
                              dynamic_axes={"grouped": {0: "batch"}, "descriptor": {0: "batch"}})
        so = ort.SessionOptions()
        so.intra_op_num_threads = 2
        sess = ort.InferenceSession(onnx_path, so, providers=["CPUExecutionProvider"])
        desc_onnx = np.concatenate([sess.run(["descriptor"], {"grouped": grouped[i:i + 1].numpy()})[0]
                                    for i in range(len(keypts))]
                                   + [sess.run(["descriptor"], {"grouped": grouped.numpy()})[0]])
        batched = desc_onnx[len(keypts):]
        desc_onnx = desc_onnx[:len(keypts)]
        cos = (desc_onnx * desc_torch).sum(1) / (np.linalg.norm(desc_onnx, axis=1) * np.linalg.norm(desc_torch, axis=1))
        entry = {
            "checkpoint": MODELS[name][0],
            "checkpoint_sha256": sha256(os.path.join(a.weights, MODELS[name][0])),
            "descriptor_net_args": list(MODELS[name][1]),
            "cloud": rel,
            "keypoint_indices": kidx.tolist(),
            "onnx_sha256": sha256(onnx_path),
            "onnx_bytes": os.path.getsize(onnx_path),
            "max_abs_diff_onnx_vs_torch": float(np.abs(desc_onnx - desc_torch).max()),
            "max_abs_diff_batched_vs_single": float(np.abs(batched - desc_onnx).max()),
            "max_abs_descriptor": float(np.abs(desc_torch).max()),
            "min_cosine_onnx_vs_torch": float(cos.min()),
            "seconds": round(time.time() - t0, 1),
        }
        report["models"][name] = entry
        np.savez(os.path.join(a.out_dir, f"parity-{name}.npz"), keypoints=keypts.astype(np.float32),
                 patches=patches.astype(np.float32), local=local.numpy().astype(np.float32),
                 grouped=grouped.numpy().astype(np.float32), desc_torch=desc_torch.astype(np.float32),
                 desc_onnx=desc_onnx.astype(np.float32))
        print(name, json.dumps(entry), flush=True)
    with open(os.path.join(a.out_dir, "report.json"), "w") as f:
        json.dump(report, f, indent=1)


if __name__ == "__main__":
    main()
