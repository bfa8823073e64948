"""``gsplat.csrc`` for a machine that has built gsplat's CUDA extension before.

gsplat imports ``gsplat.csrc`` (a prebuilt extension) before it compiles its CUDA kernels on first use
(about 70 s on the lent 16-core machine). tools/workstation_check.sh installs this module as
``gsplat/csrc.py`` when the extension built by an earlier call there travels with the tree
(``.gsplat/gsplat_cuda.so.xz``, unpacked to ``WCBENCH_GSPLAT_SO``): it loads that file and stands in
for the module. Any failure (another torch, another CUDA) raises ImportError, and gsplat builds its
kernels as it would have.
"""

from __future__ import annotations

import importlib.util
import os
import sys

try:
    _spec = importlib.util.spec_from_file_location("gsplat_cuda", os.environ["WCBENCH_GSPLAT_SO"])
    assert _spec is not None and _spec.loader is not None
    _module = importlib.util.module_from_spec(_spec)
    _spec.loader.exec_module(_module)
except Exception as exc:  # any failure means: build it instead
    raise ImportError(f"the prebuilt gsplat extension does not load: {exc}") from exc
sys.modules[__name__] = _module
