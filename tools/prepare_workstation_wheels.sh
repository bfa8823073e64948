#!/usr/bin/env bash
# Run HERE (a machine that reaches PyPI), in the repository root, with PYTHON naming a Python that holds
# wcbench[model] (default python3: the sky masks are computed here), before tools/workstation_check.sh
# travels to the lent 16-core + H200 machine (docs/workstation.md). It fills .whl/ (git-ignored through
# .git/info/exclude) with what that machine lacks: wcbench's own wheel and the few dependencies its image
# does not hold, for its Python 3.12 on x86-64. The run tool's `carry` sends .whl/ and data/ with the tree
# (and .gsplat/ when WCBENCH_GSPLAT_XZ names the extension an earlier check brought back).
set -euo pipefail
cd "$(git rev-parse --show-toplevel)"
grep -qx '/.whl/' "$(git rev-parse --git-path info/exclude)" 2>/dev/null || echo '/.whl/' >> "$(git rev-parse --git-path info/exclude)"
grep -qx '/data/' "$(git rev-parse --git-path info/exclude)" 2>/dev/null || echo '/data/' >> "$(git rev-parse --git-path info/exclude)"
rm -rf .whl && mkdir -p .whl
python3 -m pip wheel --no-deps -q -w .whl .
plat=(--platform manylinux_2_28_x86_64 --platform manylinux_2_27_x86_64 --platform manylinux_2_17_x86_64
      --platform manylinux2014_x86_64 --platform manylinux1_x86_64)
# gsplat (pure Python; it compiles its CUDA kernels on first use with the machine's nvcc), its pure
# dependency, and the three of wcbench's dependencies that image lacks (KINDS.md's package list)
python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp "${plat[@]}" \
    -d .whl gsplat==1.5.3 platformdirs PyMaxflow
# the one real scene the check trains on (pandaset_002, 30 frames), beside the tree, with the sky masks
# this machine's segmentation finds: that machine's OpenCV 5 has no cv2.ml (the segmentation's forest)
rm -rf data && mkdir -p data && cp -r "${WCBENCH_DATA:-../shared/data}/pandaset_002" data/
"${PYTHON:-python3}" tools/export_sky_masks.py data/pandaset_002
# gsplat's extension as an earlier call built it there (saved from its gsplat_cuda.so.xz), if any: no build
grep -qx '/.gsplat/' "$(git rev-parse --git-path info/exclude)" 2>/dev/null || echo '/.gsplat/' >> "$(git rev-parse --git-path info/exclude)"
if [[ -n "${WCBENCH_GSPLAT_XZ:-}" ]]; then mkdir -p .gsplat && cp "$WCBENCH_GSPLAT_XZ" .gsplat/gsplat_cuda.so.xz; fi
du -sh .whl data .gsplat 2>/dev/null
