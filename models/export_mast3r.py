#!/usr/bin/env python3
"""Export MASt3R (naver/mast3r, CC BY-NC-SA 4.0 weights) to ONNX with the signature cgenreg reads.

Run this on your own machine (it needs the mast3r + dust3r sources, torch, and the checkpoint
MASt3R_ViTLarge_BaseDecoder_512_catmlpdpt_metric.pth, about 2.7 GB). cgenreg never downloads it.

    git clone --recursive https://github.com/naver/mast3r && cd mast3r   # tested layout: mast3r e87470bc, dust3r 9869e71f
    pip install torch onnx onnxruntime -r requirements.txt -r dust3r/requirements.txt
    python3 /path/to/cgenreg/models/export_mast3r.py \
        --weights checkpoints/MASt3R_ViTLarge_BaseDecoder_512_catmlpdpt_metric.pth \
        --out mast3r_512.onnx
    cgenreg ... --vfm mast3r --vfm-model mast3r_512.onnx

Graph contract (src/vfm/mast3r.rs; reference section 13):
    inputs  img1, img2       float32 [B, 3, 384, 512] in [-1, 1]  ((u8/255 - 0.5)/0.5, 9 zero rows at the bottom
                                                                   for a 960x704 frame resized to 512x375)
    outputs desc_1, desc_2   float32 [B, 384, 512, 24]  unit-norm per pixel (view 1 conditioned on view 2, and back)
            desc_conf_1, desc_conf_2 float32 [B, 384, 512]   (exported, unused by cgenreg, as in the reference)
            pts3d_1, pts3d_2 float32 [B, 384, 512, 3], conf_1, conf_2 [B, 384, 512]
true_shape is fixed to [384, 512] inside the graph, as in the reference collate (the padding counts as image).
RoPE uses the pure-PyTorch path (the cuRoPE CUDA kernel cannot be exported). The weights need the ONNX
external-data format (> 2 GB): the .onnx file and its .onnx.data file must stay side by side.
"""
import argparse
import os
import sys

import torch


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--weights", required=True)
    ap.add_argument("--out", default="mast3r_512.onnx")
    ap.add_argument("--mast3r-root", default=".", help="folder of the mast3r checkout (with dust3r inside)")
    ap.add_argument("--opset", type=int, default=17)
    args = ap.parse_args()

    sys.path.insert(0, os.path.abspath(args.mast3r_root))
    sys.path.insert(0, os.path.join(os.path.abspath(args.mast3r_root), "dust3r"))
    # croco's pos_embed uses the cuRoPE CUDA extension when `models.curope` imports; make that import
    # fail so it defines its pure-PyTorch RoPE2D (the only one that exports).
    sys.modules["models.curope"] = None
    from mast3r.model import AsymmetricMASt3R  # noqa: E402

    model = AsymmetricMASt3R.from_pretrained(args.weights).eval().float()

    class Wrapper(torch.nn.Module):
        def __init__(self, m):
            super().__init__()
            self.m = m

        def forward(self, img1, img2):
            b = img1.shape[0]
            shape = torch.tensor([384, 512], dtype=torch.int64).reshape(1, 2).repeat(b, 1)
            v1 = dict(img=img1, true_shape=shape, instance=["0"])
            v2 = dict(img=img2, true_shape=shape, instance=["0"])
            r1, r2 = self.m(v1, v2)
            return (
                r1["desc"], r2["desc"],
                r1["desc_conf"], r2["desc_conf"],
                r1["pts3d"], r2["pts3d_in_other_view"],
                r1["conf"], r2["conf"],
            )

    w = Wrapper(model).eval()
    x1 = torch.zeros(1, 3, 384, 512)
    x2 = torch.zeros(1, 3, 384, 512)
    names = ["desc_1", "desc_2", "desc_conf_1", "desc_conf_2", "pts3d_1", "pts3d_2", "conf_1", "conf_2"]
    with torch.no_grad():
        torch.onnx.export(
            w,
            (x1, x2),
            args.out,
            input_names=["img1", "img2"],
            output_names=names,
            dynamic_axes={n: {0: "B"} for n in ["img1", "img2"] + names},
            opset_version=args.opset,
            do_constant_folding=True,
            dynamo=False,
        )
    import onnx

    m = onnx.load(args.out, load_external_data=True)
    onnx.save(m, args.out, save_as_external_data=True, all_tensors_to_one_file=True,
              location=os.path.basename(args.out) + ".data")
    print("wrote", args.out)

    # Check against torch on one random pair.
    import numpy as np
    import onnxruntime as ort

    torch.manual_seed(0)
    a = torch.rand(1, 3, 384, 512) * 2 - 1
    b = torch.rand(1, 3, 384, 512) * 2 - 1
    with torch.no_grad():
        want = w(a, b)
    sess = ort.InferenceSession(args.out, providers=["CPUExecutionProvider"])
    got = sess.run(["desc_1", "desc_2"], {"img1": a.numpy(), "img2": b.numpy()})
    for g, t in zip(got, want[:2]):
        print("max |ONNX - torch| desc:", float(np.abs(g - t.numpy()).max()))


if __name__ == "__main__":
    main()
