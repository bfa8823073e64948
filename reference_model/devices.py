"""Where the model trains and renders: ``"cpu"`` (the default, numba kernels) or ``"cuda"`` (gsplat).

On CPU training is unchanged: the numba rasterizer and kernels, bit for bit the results of before; a
render composites with the inference-only kernel (:func:`on_device`, equal within float32 rounding). On a
CUDA device the model's parameters and the training step live on the GPU, the rasterizer is gsplat
(:mod:`.raster.gsplat_backend`) and the numba kernels give way to their torch twins (the SSIM of
:func:`~.training.losses.training_ssim_torch`, the sky's ``grid_sample``), which run on any torch
device. A render keeps its particles and fog on the CPU (numba) and rasterizes on the GPU through
:func:`on_device` (docs/workstation.md).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

__all__ = ["DEVICES", "check_device", "device_problem", "on_device", "rasterizer_for"]

#: The devices ``--device`` takes.
DEVICES = ("cpu", "cuda")


def device_problem(device: str) -> str | None:
    """Why ``device`` cannot train or render here (an unknown name, no CUDA, no gsplat), or ``None``.

    Imports torch only for ``"cuda"``.
    """
    if device not in DEVICES:
        return f"unknown device {device!r}; devices: {', '.join(DEVICES)}"
    if device == "cpu":
        return None
    from wcbench.reference_model.raster.gsplat_backend import gsplat_problem

    return gsplat_problem()


def check_device(device: str) -> None:
    """Raise before any work starts when ``device`` cannot be used.

    Raises
    ------
    ValueError
        One line: the device and why (:func:`device_problem`).
    """
    problem = device_problem(device)
    if problem is not None:
        raise ValueError(f"--device {device}: {problem}")


def rasterizer_for(device: str) -> Callable[..., Any]:
    """The ``rasterize``-compatible function for tensors on ``device``: numba on ``"cpu"``, gsplat on
    ``"cuda"``."""
    check_device(device)
    if device == "cpu":
        from wcbench.reference_model.raster.rasterizer import rasterize

        return rasterize
    from wcbench.reference_model.raster.gsplat_backend import rasterize_gsplat

    return rasterize_gsplat


def on_device(device: str) -> Callable[..., Any]:
    """A ``rasterize``-compatible function for CPU tensors that rasterizes on ``device``: the inputs
    go there, the outputs come back to the CPU, without gradients (rendering, where the particles
    and fog stay numpy). ``"cpu"`` returns :func:`~.raster.rasterizer.rasterize_image`, the
    inference-only compositing (a trained model's frames; training keeps ``rasterize``)."""
    inner = rasterizer_for(device)
    if device == "cpu":
        from wcbench.reference_model.raster.rasterizer import rasterize_image

        return rasterize_image
    import torch

    def rasterize_on_device(means: Any, quats: Any, scales: Any, opacities: Any, colors: Any, viewmat: Any,
                            K: Any, width: int, height: int, **options: Any) -> Any:
        dev = torch.device(device)
        background = options.pop("background", None)
        with torch.no_grad():
            moved = [torch.as_tensor(t).to(dev) for t in (means, quats, scales, opacities, colors)]
            out = inner(*moved, torch.as_tensor(viewmat), torch.as_tensor(K), width, height,
                        background=None if background is None else torch.as_tensor(background).to(dev),
                        **{**options, "absgrad": False})
        for name in ("color", "alpha", "depth", "means2d", "radii", "depths"):
            value = getattr(out, name)
            if value is not None:
                setattr(out, name, value.detach().cpu())
        return out

    return rasterize_on_device
