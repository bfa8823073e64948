"""Lens undistortion on load: images and masks become pinhole images with the same K.

drivestudio undistorts a camera's images and masks before any pinhole use when its dataset config
says ``undistort: True`` (its Waymo configs do), with ``cv2.undistort(image, K, dist)``: the output
has the source size and the source K. wcbench does the same once per file, through remap tables
built once per camera (``cv2.initUndistortRectifyMap``), and keeps the result in the cache folder so
every later reader (training, metrics, methods reading ``Frame.image_path``) sees pinhole pixels
that :meth:`wcbench.scenes.scene.Camera.project` is exact for. docs/design.md §3 gives the cost.

Pixel convention: wcbench puts pixel (i, j)'s centre at (i + 0.5, j + 0.5) in K's coordinates
(docs/design.md §2); OpenCV puts it at (i, j). The tables are built with the principal point moved
by -0.5 px so the two agree exactly (drivestudio passes K unchanged, a difference of under 0.02 px
for Waymo's FRONT lens).
"""

from __future__ import annotations

import hashlib
import os
from functools import lru_cache
from pathlib import Path

import cv2
import numpy as np

from wcbench.core.errors import InputError
from wcbench.core.paths import cache_dir

#: Cache sub-folder of the undistorted copies; bump the version when the output changes.
CACHE_SUBDIR = "undistorted-v1"
#: zlib level of the written PNGs: 1 is several times faster than the default 3 for ~10 % more bytes.
_PNG_LEVEL = 1


def has_distortion(dist: np.ndarray) -> bool:
    """Whether OpenCV coefficients ``(k1, k2, p1, p2, k3)`` [5] bend any ray."""
    return bool(np.any(np.asarray(dist, np.float64) != 0.0))


@lru_cache(maxsize=16)
def _maps(key: tuple[float, ...], width: int, height: int, fixed: bool) -> tuple[np.ndarray, np.ndarray]:
    fx, fy, cx, cy, *dist = key
    K = np.array([[fx, 0.0, cx - 0.5], [0.0, fy, cy - 0.5], [0.0, 0.0, 1.0]])
    m1, m2 = cv2.initUndistortRectifyMap(K, np.asarray(dist), None, K, (width, height), cv2.CV_32FC1)
    if fixed:
        m1, m2 = cv2.convertMaps(m1, m2, cv2.CV_16SC2)
    m1.setflags(write=False)
    m2.setflags(write=False)
    return m1, m2


def undistort_maps(K: np.ndarray, dist: np.ndarray, size: tuple[int, int], *,
                   fixed: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """The remap tables of one camera, computed once per (K, coefficients, size) and reused.

    Parameters
    ----------
    K : ndarray [3, 3]
        Intrinsics in pixels (wcbench's pixel-centre convention).
    dist : ndarray [5]
        OpenCV coefficients k1, k2, p1, p2, k3.
    size : (int, int)
        Image width and height in pixels.
    fixed : bool
        Fixed-point tables (fast bilinear remap) rather than float ones. Nearest-neighbour remap
        must use the float tables: with fixed-point ones OpenCV takes the integer part of the
        source position, a shift of up to one pixel towards the top left.

    Returns
    -------
    map1, map2 : ndarray
        Read-only tables for ``cv2.remap``: [H, W, 2] int16 and [H, W] uint16 (1/32 px steps)
        when ``fixed``, else the source x and y [H, W] float32 (OpenCV pixel centres).
    """
    key = (float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]), *map(float, np.ravel(dist)))
    return _maps(key, int(size[0]), int(size[1]), fixed)


def undistort_image(img: np.ndarray, K: np.ndarray, dist: np.ndarray, *, mask: bool = False) -> np.ndarray:
    """The pinhole image of a distorted ``img`` [H, W] or [H, W, C] with the same K.

    Colour is interpolated bilinearly (as ``cv2.undistort``); a mask takes its nearest source
    pixel, so it stays binary. Pixels whose ray leaves the source frame are 0.
    """
    h, w = img.shape[:2]
    m1, m2 = undistort_maps(K, dist, (w, h), fixed=not mask)
    return cv2.remap(img, m1, m2, cv2.INTER_NEAREST if mask else cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_CONSTANT, borderValue=0)


def copy_folder(root: Path, K: np.ndarray, dist: np.ndarray, size: tuple[int, int]) -> Path:
    """Cache folder of one scene camera's undistorted files, keyed by the scene folder, K, the
    coefficients and the image size (a recalibrated or moved scene gets a fresh folder)."""
    key = repr((str(root.resolve()), np.round(K, 9).tolist(), np.round(dist, 12).tolist(), tuple(size)))
    return cache_dir() / CACHE_SUBDIR / hashlib.sha256(key.encode()).hexdigest()[:20]


def undistorted_copy(src: Path, root: Path, folder: Path, K: np.ndarray, dist: np.ndarray, *,
                     mask: bool = False) -> Path:
    """Path of the undistorted PNG twin of ``src`` (a file under the scene folder ``root``) in
    ``folder``, at the same relative path with a ``.png`` suffix; written on first use and again
    whenever the source is newer than it.

    The file name keeps the source's stem, so prediction folders matched by the source stems still
    match. Written to a temporary name and renamed, so concurrent loaders never see half a file.

    Raises
    ------
    InputError
        If the source cannot be decoded.
    """
    dst = folder / src.relative_to(root).with_suffix(".png")
    sub = dst.parent
    try:
        if dst.stat().st_mtime_ns >= src.stat().st_mtime_ns:
            return dst
    except FileNotFoundError:
        pass
    flag = cv2.IMREAD_GRAYSCALE if mask else cv2.IMREAD_UNCHANGED
    img = cv2.imread(str(src), flag)
    if img is None:
        raise InputError(f"{src}: cannot decode the {'mask' if mask else 'image'} (needed to undistort it)")
    out = undistort_image(img, K, dist, mask=mask)
    sub.mkdir(parents=True, exist_ok=True)
    tmp = sub / f".{src.stem}.{os.getpid()}.tmp.png"
    if not cv2.imwrite(str(tmp), out, [cv2.IMWRITE_PNG_COMPRESSION, _PNG_LEVEL]):
        raise InputError(f"{tmp}: cannot write the undistorted copy of {src} (is the cache folder writable?)")
    os.replace(tmp, dst)
    return dst
