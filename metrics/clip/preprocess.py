"""CLIP image preprocessing (torch-free): PIL bicubic resize, crop, CLIP mean/std (docs/design.md §5).

This is OpenAI's ``clip.load`` transform (``Resize(224, BICUBIC)``, ``CenterCrop(224)``,
``ToTensor``, ``Normalize``) on uint8 RGB, and it equals ``transformers``' ``CLIPImageProcessor``
to float32 rounding (a test checks <= 1e-6). Two facts that change numbers:

- PIL's bicubic (a = -0.5, antialiased when shrinking) differs from OpenCV's ``INTER_CUBIC``
  (a = -0.75, no antialiasing); we use PIL.
- The crop offset is ``floor((W - 224) / 2)`` as in ``CLIPImageProcessor``; torchvision's
  ``CenterCrop`` rounds half to even instead and starts one pixel later when ``W - 224`` is
  ``3 (mod 4)``.

A 16:9 frame loses its sides under the centre crop; ``crop="squash"`` keeps the whole frame by
resizing it to 224 x 224 without keeping the aspect ratio. The choice is part of every score's
config.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from PIL import Image

from wcbench.core.image_io import to_uint8
from wcbench.metrics.base import as_float_images
from wcbench.metrics.clip.config import CLIP_MEAN, CLIP_STD

CROPS = ("center", "squash")


@dataclass(frozen=True)
class ClipPreprocess:
    """How frames become CLIP input.

    Attributes
    ----------
    size : int
        Side S of the square model input in pixels (224 for the released ViTs).
    crop : str
        ``"center"``: shortest side to S (aspect kept), then the central S x S square (the CLIP
        default; a 16:9 frame loses its sides). ``"squash"``: the whole frame resized to S x S.
    """

    size: int = 224
    crop: str = "center"

    def __post_init__(self) -> None:
        if self.crop not in CROPS:
            raise ValueError(f"crop must be one of {CROPS}, got {self.crop!r}")
        if self.size < 1:
            raise ValueError(f"size must be positive, got {self.size}")

    def config(self) -> dict[str, Any]:
        """The settings as recorded in results (part of every CLIP score's config)."""
        if self.crop == "center":
            geometry = (
                f"resize shortest side to {self.size} (PIL bicubic), center crop {self.size}x{self.size}"
            )
        else:
            geometry = f"resize to {self.size}x{self.size} (PIL bicubic, aspect not kept)"
        return {
            "size": self.size,
            "crop": self.crop,
            "geometry": geometry,
            "quantize": "round(255 x) to uint8 before resizing",
            "mean": list(CLIP_MEAN),
            "std": list(CLIP_STD),
        }

    def __call__(self, images: Any) -> np.ndarray:
        """Preprocess frames; see :func:`preprocess_images`."""
        return preprocess_images(images, size=self.size, crop=self.crop)


def uint8_batch(images: np.ndarray) -> np.ndarray:
    """Validate frames and return them as a uint8 batch (float frames through :func:`to_uint8`).

    Parameters
    ----------
    images : ndarray [B, H, W, 3] or [H, W, 3]
        RGB, float in [0, 1] or uint8.

    Returns
    -------
    ndarray [B, H, W, 3] uint8

    Raises
    ------
    ValueError
        On a wrong shape, or float values outside [0, 1] or not finite.
    """
    arr = np.asarray(images)
    frames = arr if arr.dtype == np.uint8 else as_float_images(arr, name="images")
    if frames.ndim == 3:
        frames = frames[None]
    if frames.ndim != 4 or frames.shape[-1] != 3:
        raise ValueError(f"images: expected [B, H, W, 3] or [H, W, 3], got shape {arr.shape}")
    return to_uint8(frames)


def resized_size(height: int, width: int, *, size: int = 224) -> tuple[int, int]:
    """(height, width) after scaling the shortest side to ``size``; the other side is truncated.

    The truncation ``int(size * long / short)`` is the one torchvision and transformers use.
    """
    if height <= width:
        return size, int(size * width / height)
    return int(size * height / width), size


def _one(frame: np.ndarray, size: int, crop: str) -> np.ndarray:
    img = Image.fromarray(frame, mode=None)
    h, w = frame.shape[:2]
    if crop == "squash":
        img = img.resize((size, size), Image.Resampling.BICUBIC)
        return np.asarray(img)
    nh, nw = resized_size(h, w, size=size)
    if (nh, nw) != (h, w):
        img = img.resize((nw, nh), Image.Resampling.BICUBIC)
    arr = np.asarray(img)
    top, left = (nh - size) // 2, (nw - size) // 2
    return arr[top : top + size, left : left + size]


def preprocess_images(images: Any, *, size: int = 224, crop: str = "center") -> np.ndarray:
    """Frames -> normalised CLIP input.

    Parameters
    ----------
    images : ndarray [B, H, W, 3] or [H, W, 3]
        RGB, float in [0, 1] or uint8 (sRGB as on disk). Float frames are quantised to uint8 with
        ``round(255 x)`` first, so a PNG and its float form give the same input.
    size : int
        Side S of the output.
    crop : str
        ``"center"`` or ``"squash"``; see :class:`ClipPreprocess`.

    Returns
    -------
    ndarray [B, 3, S, S] float32
        ``(x / 255 - mean) / std`` per channel with CLIP's mean/std.

    Raises
    ------
    ValueError
        On a wrong shape, dtype or value range (the message names the shape), or an unknown crop.
    """
    if crop not in CROPS:
        raise ValueError(f"crop must be one of {CROPS}, got {crop!r}")
    u8 = uint8_batch(images)
    out = np.empty((len(u8), 3, size, size), dtype=np.float32)
    mean = np.asarray(CLIP_MEAN, np.float64)
    std = np.asarray(CLIP_STD, np.float64)
    for i, frame in enumerate(u8):
        crop_u8 = _one(np.ascontiguousarray(frame), size, crop)
        out[i] = ((crop_u8.astype(np.float64) / 255.0 - mean) / std).transpose(2, 0, 1)
    return out
