#!/usr/bin/env bash
# The workstation check of issue 38, in one call on the lent 16-core + NVIDIA H200 machine
# (docs/workstation.md). That machine reaches no package registry: tools/prepare_workstation_wheels.sh
# fills .whl/ and data/ here first, and the run tool carries them (carry: [".whl", "data"]).
# It writes five files under $OUT (the run tool brings back 8 at most; commit the JSON under docs/bench/):
#   raster.json   bench raster --threads 1,2,4,8,16          (fwd+bwd per thread count)
#   model.json    bench model --quick --threads 1,2,4,8,16   (the training's phases per thread count)
#   train_cuda.json, train_cpu16.json  a short `default`-profile training on the GPU and on 16 threads
#   log.txt       every step's output and time: the gsplat agreement tests (CPU and CUDA), and the
#                 `paper` profile's first minutes on the GPU (its time-left lines), stopped at PAPER_S
# Each step has its own time limit, so one that hangs leaves the others' results.
set -uo pipefail
OUT=${OUT:-docs/bench/workstation}
mkdir -p "$OUT"
PAPER_S=${PAPER_S:-120}
STEPS=${STEPS:-400}
export PYTHONUNBUFFERED=1 WCBENCH_OFFLINE=1 WCBENCH_PROGRESS=0
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl \
    || { echo "workstation_check: the wheels in .whl/ did not install" >&2; exit 2; }
export PYTHONPATH=/tmp/site
# its OpenCV lacks the contrib modules (the 69 MB wheel does not travel): the guided filter's fallback
python3 -c "import cv2; cv2.ximgproc" 2>/dev/null || cp tools/ximgproc_fallback.py /tmp/site/sitecustomize.py
run() {  # run NAME SECONDS COMMAND...: one step, its output and exit status appended to $OUT/log.txt
    local name=$1 limit=$2; shift 2
    local t0=$SECONDS
    echo "== $name: $*" >> "$OUT/log.txt"
    timeout "$limit" "$@" >> "$OUT/log.txt" 2>&1
    echo "== $name: exit $? in $((SECONDS - t0)) s" | tee -a "$OUT/log.txt"
}
python3 - <<'PY' | tee "$OUT/log.txt"
import os, torch
print(f"torch {torch.__version__}, cuda {torch.cuda.is_available()}, {os.cpu_count()} cores",
      torch.cuda.get_device_name(0) if torch.cuda.is_available() else "")
PY
run agreement 300 python3 -m pytest -q -p no:cacheprovider -m "cuda or not cuda" \
    tests/reference_model/raster/test_gsplat_agreement.py
run raster 240 python3 -m wcbench bench raster --threads 1,2,4,8,16 --out "$OUT/raster.json"
run model 300 python3 -m wcbench bench model --quick --threads 1,2,4,8,16 --data-root data --out "$OUT/model.json"
run train_cuda 300 python3 -m wcbench train --scenes pandaset_002 --data-root data --holdout 5,15,25 \
    --device cuda --method-option settings.iterations="$STEPS" --out "$OUT/cuda"
run train_cpu16 300 python3 -m wcbench train --scenes pandaset_002 --data-root data --holdout 5,15,25 \
    --method-option settings.iterations="$STEPS" --out "$OUT/cpu16"
cp "$OUT/cuda/pandaset_002/training.json" "$OUT/train_cuda.json" 2>/dev/null
cp "$OUT/cpu16/pandaset_002/training.json" "$OUT/train_cpu16.json" 2>/dev/null
WCBENCH_PROGRESS=1 run paper "$PAPER_S" python3 -m wcbench train --scenes pandaset_002 --data-root data \
    --profile paper --device cuda --out "$OUT/paper"
rm -rf "$OUT/cuda" "$OUT/cpu16" "$OUT/paper"  # at most 8 files come back: the JSON, the logs above
