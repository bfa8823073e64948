#!/usr/bin/env bash
# The workstation check of issue 38 on the lent 16-core + NVIDIA H200 machine (docs/workstation.md).
# That machine reaches no package registry: tools/prepare_workstation_wheels.sh fills .whl/ and data/
# here first, and the device tool carries them (carry: [".whl", "data"]).
#
# It writes at most five files under $OUT (the tool brings back 8; commit the JSON under docs/bench/):
#   raster.json        bench raster --threads 1,2,4,8,16          (fwd+bwd per thread count)
#   model.json         bench model --quick --threads 1,2,4,8,16   (the training's phases per thread count)
#   train_cuda.json    a short `default`-profile training of pandaset_002 on the GPU (held-out PSNR)
#   train_cpu16.json   the same on the CPU's 16 threads
#   log.txt            every step's command, output, exit status and time: the gsplat agreement tests
#                      (CPU and CUDA) and the `paper` profile's first minutes (its time-left lines)
#
# One command may run 10 minutes. Each step has its own limit (seconds, overridable: LIMIT_<step>=...),
# first guesses summing to 570 s, so one that hangs or runs long leaves the others' results; ONLY picks
# steps (ONLY=raster,model), e.g. to split the check over two calls. gsplat compiles its CUDA kernels on
# first use (minutes, for Hopper only here); the agreement step pays for it.
set -uo pipefail
OUT=${OUT:-docs/bench/workstation}
ONLY=${ONLY:-agreement,train_cuda,paper,raster,model,train_cpu16}
STEPS=${STEPS:-200}
PY=${PY:-python3}
SITE=${SITE:-/tmp/site}
mkdir -p "$OUT"
export PYTHONUNBUFFERED=1 WCBENCH_OFFLINE=1 WCBENCH_PROGRESS=0 TORCH_CUDA_ARCH_LIST=${TORCH_CUDA_ARCH_LIST:-9.0}
export MAX_JOBS=${MAX_JOBS:-16}
if [[ -z "${SKIP_INSTALL:-}" ]]; then  # SKIP_INSTALL=1: the environment as it is (a dry run elsewhere)
    "$PY" -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target "$SITE" .whl/*.whl \
        || { echo "workstation_check: the wheels in .whl/ did not install" >&2; exit 2; }
    export PYTHONPATH=$SITE
    # its OpenCV lacks the contrib modules (the 69 MB wheel does not travel): the guided filter's fallback
    "$PY" -c "import cv2; cv2.ximgproc" 2>/dev/null || cp tools/ximgproc_fallback.py "$SITE/sitecustomize.py"
fi

run() {  # run STEP DEFAULT_LIMIT COMMAND...: one step if ONLY names it, its output appended to $OUT/log.txt
    local step=$1 limit_var="LIMIT_$1" limit=$2; shift 2
    [[ ",$ONLY," == *",$step,"* ]] || return 0
    limit=${!limit_var:-$limit}
    local t0=$SECONDS
    echo "== $step (limit ${limit} s): $*" >> "$OUT/log.txt"
    timeout "$limit" "$@" >> "$OUT/log.txt" 2>&1
    echo "== $step: exit $? in $((SECONDS - t0)) s" | tee -a "$OUT/log.txt"
}
"$PY" - <<'PY' 2>&1 | tee -a "$OUT/log.txt"
import os, torch, wcbench
print(f"wcbench from {wcbench.__file__}; torch {torch.__version__}; cuda {torch.cuda.is_available()};",
      f"{os.cpu_count()} cores;", torch.cuda.get_device_name(0) if torch.cuda.is_available() else "no GPU")
PY
train=(-m wcbench train --scenes pandaset_002 --data-root data --holdout 5,15,25
       --method-option "settings.iterations=$STEPS")
run agreement 200 "$PY" -m pytest -q -p no:cacheprovider -m "cuda or not cuda" \
    tests/reference_model/raster/test_gsplat_agreement.py
run train_cuda 100 "$PY" "${train[@]}" --device cuda --out "$OUT/cuda"
WCBENCH_PROGRESS=1 run paper 60 "$PY" -m wcbench train --scenes pandaset_002 --data-root data --profile paper \
    --device cuda --out "$OUT/paper"
run raster 80 "$PY" -m wcbench bench raster --threads 1,2,4,8,16 --out "$OUT/raster.json"
run model 80 "$PY" -m wcbench bench model --quick --threads 1,2,4,8,16 --out "$OUT/model.json"
run train_cpu16 50 "$PY" "${train[@]}" --out "$OUT/cpu16"
cp "$OUT/cuda/pandaset_002/training.json" "$OUT/train_cuda.json" 2>/dev/null
cp "$OUT/cpu16/pandaset_002/training.json" "$OUT/train_cpu16.json" 2>/dev/null
rm -rf "$OUT/cuda" "$OUT/cpu16" "$OUT/paper"
