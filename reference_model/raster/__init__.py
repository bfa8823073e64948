"""The differentiable CPU Gaussian rasterizer (needs torch; numba for the fast path).

:mod:`.rasterizer` is the public entry (:func:`~.rasterizer.rasterize`, an autograd function over
the numba tile kernels of :mod:`.kernels`); :mod:`.torch_twin` is the pure-torch reference the
tests compare it with; :mod:`.common` holds the guards and the output container both share.
"""
