"""Weather on a Gaussian scene: rain and snow particles (:mod:`.particles`, numba kernels in
:mod:`.particle_kernels`), Beer-Lambert fog (:mod:`.fog`, kernels in :mod:`.fog_kernels`) and the
renderer that draws them with the scene (:mod:`.renderer`, presets in ``presets.toml``)."""
