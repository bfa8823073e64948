#!/usr/bin/env bash
# The workstation check of issue 38 on the lent 16-core + NVIDIA H200 machine (docs/workstation.md).
# That machine reaches no package registry: tools/prepare_workstation_wheels.sh fills .whl/ and data/
# here first, and the device tool carries them (carry: [".whl", "data"]).
#
# It writes at most eight files under $OUT (the tool brings back 8; commit the first seven under
# docs/bench/workstation/):
#   raster.json        bench raster's per-phase profiles (case b at 480x270 and 1920x1080), threads 1,2,4,8,16
#   model.json         bench model's per-phase profile of a `default` training step, threads 2,4,8,16
#   train_cuda.json    the `default` profile's whole training of pandaset_002 on the GPU (held-out PSNR)
#   step_profile.json  where a GPU training step's time goes (tools/gpu_step_profile.py)
#   train_cpu16.json   a 200-step `default` training on the CPU's 16 threads (its time per step)
#   train_cuda200.json the same 200 steps on the GPU
#   log.txt            every step's command, output, exit status and time: gsplat's build time, the
#                      agreement tests' measured differences, the trainings' progress lines and the
#                      `paper` profile's first minute (its time-left lines)
#   gsplat_cuda.so.xz  gsplat's CUDA extension as built there (for torch and CUDA of that machine)
#
# One command may run 10 minutes and a session has 15 minutes of device time, the machine's start
# included. Each step has its own limit (seconds, overridable: LIMIT_<step>=...), cut to what is left of
# DEADLINE (560 s), so one that hangs or runs long leaves the others' results; the steps run in the
# order of what the issue needs most, and
# ONLY picks some (ONLY=raster,model), e.g. to split the check over two calls. gsplat compiles its CUDA
# kernels on first use (for Hopper only here); the `build` step pays for that while numba compiles
# ours beside it, so that no measured step includes a compilation.
set -uo pipefail
OUT=${OUT:-docs/bench/workstation}
ONLY=${ONLY:-build,agreement,train_cuda,step_profile,raster,model,train_cuda200,train_cpu16,paper}
PY=${PY:-python3}
SITE=${SITE:-/tmp/site}
DATA=${DATA:-data}
DEADLINE=${DEADLINE:-560}  # seconds from the start after which no step runs (the call's timeout_s less a margin)
mkdir -p "$OUT"
export PYTHONUNBUFFERED=1 WCBENCH_OFFLINE=1 WCBENCH_PROGRESS=0 TORCH_CUDA_ARCH_LIST=${TORCH_CUDA_ARCH_LIST:-9.0}
export MAX_JOBS=${MAX_JOBS:-16} TORCH_EXTENSIONS_DIR=${TORCH_EXTENSIONS_DIR:-/tmp/torch_extensions}
# torch's extension builder calls `ninja` from PATH: the one beside this Python (its pip package)
PATH="$(dirname "$("$PY" -c 'import sys; print(sys.executable)')"):$PATH"
export PATH
if [[ -z "${SKIP_INSTALL:-}" ]]; then  # SKIP_INSTALL=1: the environment as it is (a dry run elsewhere)
    "$PY" -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target "$SITE" .whl/*.whl \
        || { echo "workstation_check: the wheels in .whl/ did not install" >&2; exit 2; }
    export PYTHONPATH=$SITE
    # its OpenCV lacks the contrib modules (the 69 MB wheel does not travel): the guided filter's fallback
    "$PY" -c "import cv2; cv2.ximgproc" 2>/dev/null || cp tools/ximgproc_fallback.py "$SITE/sitecustomize.py"
    # gsplat's extension as an earlier call built it (carry .gsplat too): no build; ImportError -> build
    # (then nothing runs beside the build step, and the numba kernels compile in the first training's
    # preparation, which the training's time leaves out)
    if [[ -f .gsplat/gsplat_cuda.so.xz ]]; then
        export WCBENCH_GSPLAT_SO=/tmp/gsplat_cuda.so WARM=${WARM:-0}
        xz -dc .gsplat/gsplat_cuda.so.xz > "$WCBENCH_GSPLAT_SO" && cp tools/gsplat_prebuilt.py "$SITE/gsplat/csrc.py"
    fi
fi

run() {  # run STEP DEFAULT_LIMIT COMMAND...: one step if ONLY names it, its output appended to $OUT/log.txt
    local step=$1 limit_var="LIMIT_$1" limit=$2; shift 2
    [[ ",$ONLY," == *",$step,"* ]] || return 0
    limit=${!limit_var:-$limit}
    local left=$((DEADLINE - SECONDS))  # the call's own limit: a step never runs past it
    if ((left < 20)); then echo "== $step: not run, ${left} s left of DEADLINE=$DEADLINE" | tee -a "$OUT/log.txt"; return 0; fi
    ((limit > left)) && limit=$left
    local t0=$SECONDS
    echo "== $step (limit ${limit} s, $(date -u +%T)): $*" >> "$OUT/log.txt"
    timeout "$limit" "$@" >> "$OUT/log.txt" 2>&1
    echo "== $step: exit $? in $((SECONDS - t0)) s" | tee -a "$OUT/log.txt"
}
"$PY" - <<'PY' 2>&1 | tee -a "$OUT/log.txt"
import os, cv2, numpy, numba, torch, wcbench
print(f"opencv {cv2.__version__}, numpy {numpy.__version__}, numba {numba.__version__}")
print(f"wcbench from {wcbench.__file__}; torch {torch.__version__}; cuda {torch.cuda.is_available()};",
      f"{os.cpu_count()} cores;", torch.cuda.get_device_name(0) if torch.cuda.is_available() else "no GPU")
print("load average", os.getloadavg())
PY
{ nproc; grep -m1 "model name" /proc/cpuinfo; lscpu 2>/dev/null | grep -E "^(Thread|Core|Socket|NUMA node\(s\)|L3)"; } >> "$OUT/log.txt"

# gsplat's CUDA build (or the prebuilt one's load) in the foreground; beside it, numba compiles our
# kernels (cached beside the package) and a one-step CPU training compiles those of the scene analysis
# and the editor, so that no later step's time includes a compilation (WARM=0: not beside it; the default
# when the prebuilt extension travels)
# the content loss off: its VGG16 weights (59 MB) do not fit beside the scene in what the device tool
# carries (64 MB), and a training without them would skip it anyway; the CPU reference it is compared
# with is trained here the same way (docs/workstation.md)
train=(-m wcbench train --scenes pandaset_002 --data-root "$DATA" --holdout 5,15,25
       --method-option settings.content_weight=0)
run build 300 bash -c '[[ ${WARM:-1} == 0 ]] || { "$0" -m wcbench compile > "$1/warm.txt" 2>&1 && \
    "$0" "${@:2}" --method-option settings.iterations=1 --out "$1/warm" >> "$1/warm.txt" 2>&1; } &
    "$0" -c "import time; t = time.time(); from gsplat.cuda._backend import _C; \
print(\"gsplat CUDA extension:\", \"built\" if _C is not None else \"NOT BUILT\", f\"in {time.time() - t:.0f} s\", _C)"
    wait; tail -n 5 "$1/warm.txt" 2>/dev/null; rm -rf "$1/warm.txt" "$1/warm"' "$PY" "$OUT" "${train[@]}"
# the built extension comes back (xz), for a later call that cannot spend minutes on the build
so=$TORCH_EXTENSIONS_DIR/gsplat_cuda/gsplat_cuda.so
[[ -f $so ]] && xz -T0 -3 -c "$so" > "$OUT/gsplat_cuda.so.xz" && ls -l "$so" "$OUT/gsplat_cuda.so.xz" >> "$OUT/log.txt"
# gsplat against ours, and a few training steps on the GPU against the CPU's (the tests marked cuda)
run agreement 120 "$PY" -m pytest -q -s -rA -p no:cacheprovider -m "cuda or not cuda" \
    tests/reference_model/raster/test_gsplat_agreement.py tests/reference_model/training/test_paper_profile_and_device.py
# the whole `default` profile on the GPU: its held-out PSNR against the CPU's (docs/bench/model.json)
keep() {  # keep NAME: OUT/NAME/pandaset_002/training.json as OUT/train_NAME.json (the folder does not come back)
    cp "$OUT/$1/pandaset_002/training.json" "$OUT/train_$1.json" 2>/dev/null; rm -rf "${OUT:?}/$1"
}
WCBENCH_PROGRESS=1 run train_cuda 180 "$PY" "${train[@]}" --device cuda --out "$OUT/cuda"; keep cuda
# where a GPU step's time goes: synchronised ms per step, device busy time, launches, labelled parts
run step_profile 120 "$PY" tools/gpu_step_profile.py --data-root "$DATA" --device cuda --out "$OUT/step_profile.json"
WCBENCH_BENCH_RASTER_GROUPS=profile run raster 120 "$PY" -m wcbench bench raster --data-root "$DATA" \
    --threads 1,2,4,8,16 --out "$OUT/raster.json"
WCBENCH_BENCH_MODEL_GROUPS=profile run model 150 "$PY" -m wcbench bench model --data-root "$DATA" \
    --threads 2,4,8,16 --out "$OUT/model.json"
# 200 steps on each device, the same steps: the time per step of 16 CPU threads against the GPU
run train_cuda200 60 "$PY" "${train[@]}" --method-option settings.iterations=200 --device cuda --out "$OUT/cuda200"
keep cuda200
run train_cpu16 90 "$PY" "${train[@]}" --method-option settings.iterations=200 --out "$OUT/cpu16"; keep cpu16
WCBENCH_PROGRESS=1 run paper 60 "$PY" -m wcbench train --scenes pandaset_002 --data-root "$DATA" --profile paper \
    --device cuda --out "$OUT/paper"
rm -rf "${OUT:?}/paper"
