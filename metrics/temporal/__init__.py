"""Temporal metrics: flow warping error and VBench-style temporal flicker (:mod:`.flicker`)."""
