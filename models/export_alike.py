#!/usr/bin/env python3
"""Export ALIKE (Zhao et al., "ALIKE: Accurate and Lightweight Keypoint Detection and Descriptor
Extraction", IEEE TMM 2022) to ONNX for cgenreg.

    python3 -m venv /tmp/alike-venv
    /tmp/alike-venv/bin/pip install torch onnx onnxruntime pillow
    /tmp/alike-venv/bin/python models/export_alike.py --size t --out models/alike-t.onnx

Weights: `alike-{t,s,n,l}.pth` from Shiaoming/ALIKE @ 4e61fc77e75fb1cb3e7447d0a21f854cc61a0d32
(`models/`, BSD-3-Clause), copied byte for byte to shared/models/alike. No ALIKE package is on PyPI,
so ALNet is written out below from the authors' `alnet.py` (same module names, so their state dicts
load with strict=True): ConvBlock / ResBlock (Conv3x3 + BatchNorm + ReLU, 1x1 downsample convs),
MaxPool 2/4/4, 1x1 aggregation convs, bilinear upsampling x2/x8/x32 with align_corners=True,
concatenation and a 1x1 head with dim + 1 channels. The descriptors are the first `dim` channels,
the score map the sigmoid of the last; ALIKE's `extract_dense_map` zero-pads H and W up to
multiples of 32 and L2-normalises the descriptors.

Graph contract (read by src/vfm/dense.rs):
    input  image        float32 (B, 3, H, W), RGB in [0, 1], H and W multiples of 32 (dynamic B/H/W;
                        declared `32*h32` / `32*w32` so that tract can analyse the graph)
    output descriptors  float32 (B, dim, H, W)  dense descriptors, NOT L2-normalised (dim 64/96/128/128)
           heatmap      float32 (B, 1, H, W)    sigmoid score map (unused by cgenreg)
Exported with the TorchScript exporter (dynamo=False) at opset 17; BatchNorm is folded into the
convolutions by the exporter (eval mode). The script checks ONNX Runtime against the torch model on
real redkitchen frames and random inputs, runs the dense nearest-neighbour reprojection check on
frames 0 -> 20 (models/dense_check.py) and writes tests/fixtures/alike-<size>_frame0_desc.npy.
"""
import argparse
import hashlib
import os
import sys

import torch
import torch.nn.functional as F
from torch import nn

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import dense_check as dc  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))

# The authors' `alike.py` configs.
CONFIGS = {
    "t": dict(c1=8, c2=16, c3=32, c4=64, dim=64, single_head=True),
    "s": dict(c1=8, c2=16, c3=48, c4=96, dim=96, single_head=True),
    "n": dict(c1=16, c2=32, c3=64, c4=128, dim=128, single_head=True),
    "l": dict(c1=32, c2=64, c3=128, c4=128, dim=128, single_head=False),
}


def conv3x3(i, o):
    return nn.Conv2d(i, o, 3, padding=1, bias=False)


def conv1x1(i, o):
    return nn.Conv2d(i, o, 1, bias=False)


class ConvBlock(nn.Module):
    def __init__(self, i, o):
        super().__init__()
        self.gate = nn.ReLU()
        self.conv1, self.bn1 = conv3x3(i, o), nn.BatchNorm2d(o)
        self.conv2, self.bn2 = conv3x3(o, o), nn.BatchNorm2d(o)

    def forward(self, x):
        x = self.gate(self.bn1(self.conv1(x)))
        return self.gate(self.bn2(self.conv2(x)))


class ResBlock(nn.Module):
    """torchvision's BasicBlock with stride 1 and a 1x1 (biased) downsample conv."""

    def __init__(self, i, o):
        super().__init__()
        self.gate = nn.ReLU()
        self.conv1, self.bn1 = conv3x3(i, o), nn.BatchNorm2d(o)
        self.conv2, self.bn2 = conv3x3(o, o), nn.BatchNorm2d(o)
        self.downsample = nn.Conv2d(i, o, 1)

    def forward(self, x):
        out = self.gate(self.bn1(self.conv1(x)))
        out = self.bn2(self.conv2(out))
        return self.gate(out + self.downsample(x))


class ALNet(nn.Module):
    def __init__(self, c1, c2, c3, c4, dim, single_head):
        super().__init__()
        self.gate = nn.ReLU()
        self.pool2 = nn.MaxPool2d(2, 2)
        self.pool4 = nn.MaxPool2d(4, 4)
        self.block1 = ConvBlock(3, c1)
        self.block2 = ResBlock(c1, c2)
        self.block3 = ResBlock(c2, c3)
        self.block4 = ResBlock(c3, c4)
        self.conv1 = conv1x1(c1, dim // 4)
        self.conv2 = conv1x1(c2, dim // 4)
        self.conv3 = conv1x1(c3, dim // 4)
        self.conv4 = conv1x1(dim, dim // 4)
        self.upsample2 = nn.Upsample(scale_factor=2, mode="bilinear", align_corners=True)
        self.upsample8 = nn.Upsample(scale_factor=8, mode="bilinear", align_corners=True)
        self.upsample32 = nn.Upsample(scale_factor=32, mode="bilinear", align_corners=True)
        self.single_head = single_head
        if not single_head:
            self.convhead1 = conv1x1(dim, dim)
        self.convhead2 = conv1x1(dim, dim + 1)

    def forward(self, image):
        x1 = self.block1(image)
        x2 = self.block2(self.pool2(x1))
        x3 = self.block3(self.pool4(x2))
        x4 = self.block4(self.pool4(x3))
        x1 = self.gate(self.conv1(x1))
        x2 = self.gate(self.conv2(x2))
        x3 = self.gate(self.conv3(x3))
        x4 = self.gate(self.conv4(x4))
        x = torch.cat([x1, self.upsample2(x2), self.upsample8(x3), self.upsample32(x4)], dim=1)
        if not self.single_head:
            x = self.gate(self.convhead1(x))
        x = self.convhead2(x)
        return x[:, :-1], torch.sigmoid(x[:, -1:])


def simple_nms(scores, r):
    """ALIKE's (SuperPoint's) NMS on a (B, 1, H, W) score map."""
    pool = lambda x: F.max_pool2d(x, 2 * r + 1, 1, r)  # noqa: E731
    zeros = torch.zeros_like(scores)
    max_mask = scores == pool(scores)
    for _ in range(2):
        supp = pool(max_mask.float()) > 0
        supp_scores = torch.where(supp, zeros, scores)
        max_mask = max_mask | ((supp_scores == pool(supp_scores)) & ~supp)
    return torch.where(max_mask, scores, zeros)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--size", default="t", choices=sorted(CONFIGS))
    ap.add_argument("--weights", default=None, help="default: ../shared/models/alike/alike-<size>.pth")
    ap.add_argument("--out", default=None, help="default: models/alike-<size>.onnx")
    ap.add_argument("--fixture", default=None)
    args = ap.parse_args()
    name = f"alike-{args.size}"
    weights = args.weights or os.path.join(HERE, "..", "..", "shared", "models", "alike", f"{name}.pth")
    out = args.out or os.path.join(HERE, f"{name}.onnx")
    fixture = args.fixture or os.path.join(HERE, "..", "tests", "fixtures", f"{name}_frame0_desc.npy")

    torch.set_num_threads(1)
    cfg = CONFIGS[args.size]
    net = ALNet(**cfg).eval()
    net.load_state_dict(torch.load(weights, map_location="cpu", weights_only=False), strict=True)
    print(f"{name}: {sum(p.numel() for p in net.parameters())} parameters, dim {cfg['dim']}, from {weights}")

    torch.onnx.export(
        net,
        (torch.rand(1, 3, 480, 640),),
        out,
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

    m = onnx.load(out)
    m.producer_name = "cgenreg models/export_alike.py"
    dc.declare_multiple(m, 32)
    onnx.checker.check_model(m)
    onnx.save(m, out)
    print("operators:", sorted({n.op_type for n in m.graph.node}))

    import onnxruntime as ort

    sess = ort.InferenceSession(out, providers=["CPUExecutionProvider"])
    raw, unit = dc.compare_onnx(sess, lambda x: net(x)[0], 32, name)
    assert unit < 5e-3, unit
    dc.compare_tract(out, 32, name)

    def dense(x):
        with torch.no_grad():
            return F.normalize(net(dc.pad_to(x, 32))[0][0, :, :480, :640], dim=0)

    def keypoints(x):
        # ALIKE's DKD at the demo's defaults: NMS radius 2, scores > 0.2, borders of radius + 1 px out
        with torch.no_grad():
            s = net(dc.pad_to(x, 32))[1][:, :, :480, :640]
        s = simple_nms(s, 2)[0, 0]
        s[:3], s[-3:], s[:, :3], s[:, -3:] = 0, 0, 0, 0
        v, u = torch.nonzero(s > 0.2, as_tuple=True)
        return torch.stack([u, v], 1).numpy()

    dc.reprojection_check(dense, keypoints=keypoints, label=name)
    dc.reprojection_check(dense, a=0, b=40, label=name)
    dc.write_fixture(fixture, dense(dc.load_rgb(0)), dc.FIXTURE_PIXELS)

    sha = hashlib.sha256(open(out, "rb").read()).hexdigest()
    wsha = hashlib.sha256(open(weights, "rb").read()).hexdigest()
    print(f"{out}: {os.path.getsize(out)} bytes, sha256 {sha}")
    print(f"weights {weights}: sha256 {wsha}")
    print("torch", torch.__version__, "onnx", onnx.__version__, "onnxruntime", ort.__version__)


if __name__ == "__main__":
    main()
