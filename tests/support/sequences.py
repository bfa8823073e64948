"""Small synthetic frame sequences for metric tests."""

from __future__ import annotations

import cv2
import numpy as np


def translated_sequence(n: int = 4, shift: int = 3, size: tuple[int, int] = (96, 128)) -> np.ndarray:
    """[n, H, W, 3] float32 in [0, 1]: smooth random texture moving left by ``shift`` px per frame."""
    rng = np.random.default_rng(0)
    base = cv2.GaussianBlur(rng.random((size[0], size[1] + n * shift, 3)).astype(np.float32), (0, 0), 2.0)
    base = (base - base.min()) / (base.max() - base.min())
    # content moves left by `shift` px per frame
    return np.stack([base[:, k * shift : k * shift + size[1]] for k in range(n)])


