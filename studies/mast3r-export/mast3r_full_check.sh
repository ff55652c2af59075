#!/usr/bin/env bash
# The MASt3R export at the released size, proven on MASt3R's own code (issue 10, item 4).
#
# tests/it/mast3r_export.rs proves the export on a small random-weight checkpoint; this does the same
# at the released model's own constructor (ViT-L encoder, ViT-B decoder, 695 M parameters, 2.7 GB of
# weights, over ONNX's 2 GB protobuf line). It peaked at 7.3 GB resident and took 5 min on a 16-core
# machine (studies/mast3r-export/results/full-check-h200.txt), so it is a script, not a test:
#   1. a random-weight checkpoint in the real format, with the released training constructor verbatim
#      (tests/fixtures/make_random_mast3r_checkpoint.py --size released);
#   2. models/export_mast3r.py, unchanged, run from the mast3r checkout as a user runs it (it checks
#      ONNX Runtime against the unmodified torch model on random pairs, B = 1 and 2);
#   3. cgenreg loads the export (examples/mast3r_describe.rs, native ONNX Runtime) and describes two
#      real 7-Scenes frames at 640x480 and resized to 960x704;
#   4. the unmodified torch model describes the same tensors on CPU and, when a GPU is there, on CUDA
#      in fp32 (the authors' setting), and on the reference (PIL) collate;
#   5. tests/fixtures/mast3r_compare.py prints every difference and fails above 1e-3 against torch CPU;
#   6. the pair-conditioned path end to end on redkitchen/0-1 (oracle RGB, K = 1; $MANIFEST, default
#      assets/manifests/redkitchen-staged.toml, $FRAMES depth frames per fragment, default 50).
#
# usage: studies/mast3r-export/mast3r_full_check.sh MAST3R_ROOT DATA_DIR WORK_DIR [EXAMPLE_BIN]
#   MAST3R_ROOT  a recursive mast3r checkout (../shared/third_party/naver-mast3r)
#   DATA_DIR     $CGENREG_DATA (7scenes-redkitchen-rgbd frames 0 and 20; step 6 also fragments 0 and 1
#                of 3dmatch-redkitchen, gt.log and the frames the manifest gives them)
#   WORK_DIR     scratch for the checkpoint and the export (about 6 GB)
# SIZE=small runs the same steps on the test's small checkpoint (a quick dry run of this script).
# Python: $PYTHON (default python3) with torch, onnx, onnxruntime, numpy, pillow, einops, huggingface_hub.
set -euo pipefail
here=$(cd "$(dirname "$0")/../.." && pwd)
M3=$(cd "$1" && pwd)
DATA=$(cd "$2" && pwd)
W=$3
EX=${4:-$here/target/release/examples/mast3r_describe}
MANIFEST=${MANIFEST:-$here/assets/manifests/redkitchen-staged.toml}
PY=${PYTHON:-python3}
mkdir -p "$W"
W=$(cd "$W" && pwd)
step() { echo; echo "== $(date -u +%H:%M:%S) $*"; }

"$PY" -c 'import torch, onnx, onnxruntime; print("torch", torch.__version__, "cuda", torch.cuda.is_available(),
"onnx", onnx.__version__, "onnxruntime", onnxruntime.__version__)'
ORT_DYLIB_PATH=$("$PY" -c 'import onnxruntime, glob, os
print(sorted(glob.glob(os.path.join(os.path.dirname(onnxruntime.__file__), "capi", "libonnxruntime.so*")))[0])')
export ORT_DYLIB_PATH

step "1. random-weight checkpoint, released constructor"
"$PY" "$here/tests/fixtures/make_random_mast3r_checkpoint.py" --size "${SIZE:-released}" --mast3r-root "$M3" \
  --out "$W/mast3r_released.pth"

step "2. models/export_mast3r.py, unchanged, from the mast3r checkout"
(cd "$M3" && "$PY" "$here/models/export_mast3r.py" --weights "$W/mast3r_released.pth" \
  --out "$W/mast3r_512.onnx")
ls -l "$W"

step "3. cgenreg describes real frames with the export"
F="$DATA/7scenes-redkitchen-rgbd"
"$EX" "$W/mast3r_512.onnx" "$W" f640 "$F/frame-000000.color.jpg" "$F/frame-000020.color.jpg"
"$EX" "$W/mast3r_512.onnx" "$W" f960 "$F/frame-000000.color.jpg" "$F/frame-000020.color.jpg" 960x704

step "4. the unmodified torch model on the same tensors"
"$PY" "$here/tests/fixtures/mast3r_torch_reference.py" --mast3r-root "$M3" --weights "$W/mast3r_released.pth" \
  --dir "$W" --pair f640 --pair f960
if "$PY" -c 'import torch, sys; sys.exit(0 if torch.cuda.is_available() else 1)'; then
  "$PY" "$here/tests/fixtures/mast3r_torch_reference.py" --mast3r-root "$M3" \
    --weights "$W/mast3r_released.pth" --dir "$W" --pair f640 --pair f960 --device cuda --tag cuda
else
  echo "no CUDA device: the torch CUDA comparison is skipped"
fi

step "5. compare"
"$PY" "$here/tests/fixtures/mast3r_compare.py" --dir "$W" --pair f640 --pair f960

step "6. end to end: redkitchen/0-1, oracle RGB, MASt3R (random weights: the pose means nothing), K = 1"
CGENREG_DATA="$DATA" "$EX" "$W/mast3r_512.onnx" --e2e "$MANIFEST" redkitchen/0-1 ${FRAMES:-50}
step "done"
