#!/usr/bin/env python3
"""Export MASt3R (naver/mast3r, CC BY-NC-SA 4.0 weights) to ONNX with the signature cgenreg reads.

Run this on your own machine (it needs the mast3r + dust3r + croco sources, torch, onnx, onnxruntime,
and the checkpoint MASt3R_ViTLarge_BaseDecoder_512_catmlpdpt_metric.pth, about 2.7 GB). cgenreg never
downloads it.

    git clone --recursive https://github.com/naver/mast3r && cd mast3r
    pip install torch onnx onnxruntime einops huggingface_hub numpy
    python3 /path/to/cgenreg/models/export_mast3r.py \
        --weights checkpoints/MASt3R_ViTLarge_BaseDecoder_512_catmlpdpt_metric.pth \
        --out mast3r_512.onnx
    cgenreg ... --vfm mast3r --vfm-model mast3r_512.onnx

Verified (tests/mast3r_export.rs, on a small random-weight checkpoint in the real format made by
tests/fixtures/make_random_mast3r_checkpoint.py) with mast3r f5209afc, dust3r 4c24a6eb, croco d7de0705
and torch 2.15.0 (CPU), onnx 1.23, onnxruntime 1.31.1; and at the released size (a random-weight
checkpoint with the released training constructor, 695 M parameters, 2.7 GB of external data) by
studies/mast3r-export/mast3r_full_check.sh with torch 2.11.0 (CUDA and CPU), onnx 1.23.1, onnxruntime 1.30.0
(studies/mast3r-export/results/full-check-h200.txt). The trained weights themselves were never at hand.

Graph contract (src/vfm/mast3r.rs; reference sections 6 and 13):
    inputs  img1, img2       float32 [B, 3, 384, 512] in [-1, 1]  ((u8/255 - 0.5)/0.5, zero rows at the
                                                                   bottom: 9 for a 960x704 frame resized
                                                                   to 512x375, none for 640x480)
    outputs desc_1, desc_2   float32 [B, 384, 512, 24]  unit-norm per pixel (view 1 conditioned on view 2,
                                                         and back)
            desc_conf_1, desc_conf_2 float32 [B, 384, 512]   (exported, unused by cgenreg, as in the reference)
            pts3d_1, pts3d_2 float32 [B, 384, 512, 3] (pts3d_2 = view 2 in view 1's frame), conf_1, conf_2
true_shape is fixed to [384, 512] inside the graph, as in the reference collate (the padding counts as
image). B is dynamic. RoPE uses croco's pure-PyTorch RoPE2D (the cuRoPE CUDA kernel cannot be exported).
Two ops of the model code have no ONNX symbolic; see `export_rewrites`.

Output files: OUT and OUT.data (all weights, ONNX external-data format, needed above 2 GB). Keep them side
by side: cgenreg reads OUT.data through the location recorded in OUT, and includes it in the model id.
Both are written under temporary names and renamed into place once the check below has passed.

Check: the script runs the exported graph with ONNX Runtime and the unmodified torch model on random
pairs at B = 1 and B = 2, prints the max difference of every output, and exits non-zero above --tol.
"""
import argparse
import os
import shutil
import sys
import tempfile

OUTPUTS = ["desc_1", "desc_2", "desc_conf_1", "desc_conf_2", "pts3d_1", "pts3d_2", "conf_1", "conf_2"]


def export_rewrites():
    """Two ops of the model code that the TorchScript ONNX exporter (opset 17) has no symbolic for.

    - `torch.cartesian_prod` in croco's PositionGetter (patch positions): replaced by the same grid
      from `meshgrid` + `stack`; asserted equal to `cartesian_prod` on the 24x32 patch grid.
    - `torch.expm1` in dust3r's `reg_dense_depth` (depth_mode 'exp', pts3d only; ONNX has no Expm1):
      exported as Exp(x) - 1. torch keeps its own expm1, so the check compares the exported graph with
      the unmodified forward.
    """
    import torch
    import models.blocks  # croco's models package, on sys.path once mast3r is imported

    def positions(self, b, h, w, device):
        if (h, w) not in self.cache_positions:
            y = torch.arange(h, device=device)
            x = torch.arange(w, device=device)
            gy, gx = torch.meshgrid(y, x, indexing="ij")
            self.cache_positions[h, w] = torch.stack([gy.reshape(-1), gx.reshape(-1)], dim=-1)
        return self.cache_positions[h, w].view(1, h * w, 2).expand(b, -1, 2).clone()

    want = torch.cartesian_prod(torch.arange(24), torch.arange(32))
    got = positions(models.blocks.PositionGetter(), 1, 24, 32, "cpu")[0]
    assert torch.equal(want, got), "meshgrid positions differ from cartesian_prod"
    models.blocks.PositionGetter.__call__ = positions

    def expm1(g, x):
        one = g.op("Constant", value_t=torch.tensor(1.0, dtype=torch.float32))
        return g.op("Sub", g.op("Exp", x), one)

    torch.onnx.register_custom_op_symbolic("aten::expm1", expm1, 9)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--weights", required=True)
    ap.add_argument("--out", default="mast3r_512.onnx")
    ap.add_argument("--mast3r-root", default=".", help="folder of the mast3r checkout (with dust3r inside)")
    ap.add_argument("--opset", type=int, default=17)
    ap.add_argument("--tol", type=float, default=1e-3, help="max |ONNX - torch| allowed on desc_1/desc_2")
    args = ap.parse_args()

    root = os.path.abspath(args.mast3r_root)
    if not os.path.isdir(os.path.join(root, "mast3r")) or not os.path.isdir(os.path.join(root, "dust3r", "dust3r")):
        sys.exit(f"--mast3r-root {root}: expected a mast3r checkout with mast3r/ and dust3r/dust3r/ inside "
                 "(git clone --recursive https://github.com/naver/mast3r)")
    sys.path.insert(0, root)
    sys.path.insert(0, os.path.join(root, "dust3r"))
    # croco's pos_embed uses the cuRoPE CUDA extension when `models.curope` imports; make that import
    # fail so it defines its pure-PyTorch RoPE2D (the only one that exports).
    sys.modules["models.curope"] = None
    import numpy as np
    import onnx
    import onnxruntime as ort
    import torch
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
            v2 = dict(img=img2, true_shape=shape, instance=["1"])
            r1, r2 = self.m(v1, v2)
            return (
                r1["desc"], r2["desc"],
                r1["desc_conf"], r2["desc_conf"],
                r1["pts3d"], r2["pts3d_in_other_view"],
                r1["conf"], r2["conf"],
            )

    w = Wrapper(model).eval()
    # Reference outputs from the unmodified model, before the export-only rewrites.
    torch.manual_seed(0)
    tests = [(torch.rand(b, 3, 384, 512) * 2 - 1, torch.rand(b, 3, 384, 512) * 2 - 1) for b in (1, 2)]
    with torch.no_grad():
        want = [[t.numpy() for t in w(a, c)] for a, c in tests]

    export_rewrites()
    model.patch_embed.position_getter.cache_positions.clear()
    out = os.path.abspath(args.out)
    out_dir, base = os.path.dirname(out), os.path.basename(out)
    work = tempfile.mkdtemp(prefix=".export-mast3r-", dir=out_dir)
    try:
        # torch writes one file per tensor when the model exceeds 2 GB; export into a scratch folder,
        # then re-save with every weight in one BASE.data file.
        raw = os.path.join(work, "raw.onnx")
        with torch.no_grad():
            torch.onnx.export(
                w,
                (torch.zeros(1, 3, 384, 512), torch.zeros(1, 3, 384, 512)),
                raw,
                input_names=["img1", "img2"],
                output_names=OUTPUTS,
                dynamic_axes={n: {0: "B"} for n in ["img1", "img2"] + OUTPUTS},
                opset_version=args.opset,
                do_constant_folding=True,
                dynamo=False,
            )
        m = onnx.load(raw, load_external_data=True)
        staged = os.path.join(work, base)
        onnx.save(m, staged, save_as_external_data=True, all_tensors_to_one_file=True,
                  location=base + ".data", size_threshold=0)
        del m
        onnx.checker.check_model(staged)

        sess = ort.InferenceSession(staged, providers=["CPUExecutionProvider"])
        worst = 0.0
        for (a, c), ref in zip(tests, want):
            got = sess.run(OUTPUTS, {"img1": a.numpy(), "img2": c.numpy()})
            for name, g, t in zip(OUTPUTS, got, ref):
                if g.shape != t.shape:
                    sys.exit(f"{name}: ONNX shape {g.shape}, torch shape {t.shape}")
                d = float(np.abs(g - t).max())
                print(f"B={a.shape[0]} {name:12s} max |ONNX - torch| = {d:.3g}")
                if name.startswith("desc_") and "conf" not in name:
                    worst = max(worst, d)
        if not worst <= args.tol:
            sys.exit(f"ONNX descriptors differ from torch by {worst:.3g} > --tol {args.tol}; nothing written")
        del sess
        # Data first: an OUT that exists always has its weights next to it.
        os.replace(staged + ".data", out + ".data")
        os.replace(staged, out)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    print(f"wrote {out} and {out}.data (max |ONNX - torch| on descriptors {worst:.3g})")


if __name__ == "__main__":
    main()
