"""wcbench: weather editing of driving scenes, a reference implementation and a benchmark harness.

The evaluation side (scenes, method adapters, metrics, results) needs no torch; the reference
model (``wcbench.reference_model``) needs the ``[model]`` extra.
"""

__version__ = "0.1.0"
