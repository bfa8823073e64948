"""Scenes: the data model (:mod:`.scene`), loaders of the on-disk formats (:mod:`.loaders`), scene
sets as TOML data (:mod:`.sets`, files in ``specs/``), the built-in procedural scene (:mod:`.demo`)
and the procedural scenes with ground-truth weather (:mod:`.synth`)."""
