"""Metrics for weather editing: a functional API on float RGB arrays in [0, 1] and Metric classes.

Functional forms (shapes [H, W, 3] or [T, H, W, 3], float RGB in [0, 1] or uint8):

- :func:`psnr`, :func:`ssim` against a reference;
- :func:`temporal_flicker` and :func:`flow_warp_error` on sequences [T, H, W, 3].

Metric classes (update/compute) are listed by ``wcbench metrics list`` and resolved through
:data:`wcbench.metrics.registry.METRICS`. Nothing here imports torch.
"""

from wcbench.metrics.base import Metric, MetricContext, MetricValue
from wcbench.metrics.flicker import flow_warp_error, temporal_flicker
from wcbench.metrics.psnr import psnr
from wcbench.metrics.ssim import ssim

__all__ = [
    "Metric",
    "MetricContext",
    "MetricValue",
    "flow_warp_error",
    "psnr",
    "ssim",
    "temporal_flicker",
]
