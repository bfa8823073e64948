"""Reading and writing frames strictly: 8-bit RGB in, float32 RGB in [0, 1] out.

Images on disk are uint8 sRGB. Anything else (grayscale, 16-bit, alpha, unreadable bytes) is an
:class:`~wcbench.core.errors.InputError` naming the file and what was expected, never a silent
conversion that would shift a metric.

A damaged PNG or MP4 is refused from its structure before OpenCV sees it: libpng and ffmpeg print
their own complaints straight to the terminal, ahead of wcbench's one message.
"""

from __future__ import annotations

import re
import struct
import warnings
import zlib
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np
from PIL import Image

from wcbench.core.errors import InputError
from wcbench.core.storage import atomic_path, atomic_write_bytes

#: The largest image read: at most this many pixels a side and in all (8K UHD is 33 MP). Larger
#: sizes are refused from the file's header, before anything is decoded (docs/design.md §9).
MAX_IMAGE_SIDE = 16384
MAX_IMAGE_PIXELS = 64_000_000

IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp")
VIDEO_EXTENSIONS = (".mp4", ".avi", ".mov", ".mkv", ".webm")
_NUM = re.compile(r"(\d+)")


def natural_key(name: str) -> list[object]:
    """Sort key that orders ``frame2`` before ``frame10``."""
    return [int(part) if part.isdigit() else part.lower() for part in _NUM.split(name)]


def _check_rgb8(img: np.ndarray | None, path: Path) -> np.ndarray:
    expected = "expected an 8-bit RGB image"
    if img is None:
        raise InputError(f"{path}: cannot decode image (corrupt or not an image); {expected}")
    if img.dtype != np.uint8:
        bits = img.dtype.itemsize * 8
        raise InputError(f"{path}: {bits}-bit image ({img.dtype}); {expected} (8 bits per channel)")
    if img.ndim == 2 or (img.ndim == 3 and img.shape[2] == 1):
        raise InputError(f"{path}: grayscale image; {expected} with 3 channels")
    if img.ndim == 3 and img.shape[2] == 4:
        raise InputError(f"{path}: image has an alpha channel (RGBA); {expected} without alpha")
    if img.ndim != 3 or img.shape[2] != 3:
        raise InputError(f"{path}: image of shape {img.shape}; {expected} [H, W, 3]")
    return img


def check_image_size(width: int, height: int, where: str | Path) -> None:
    """Refuse a declared or decoded size of 0 or above :data:`MAX_IMAGE_SIDE` / :data:`MAX_IMAGE_PIXELS`.

    Raises
    ------
    InputError
        Naming ``where`` and the size.
    """
    too_big = width > MAX_IMAGE_SIDE or height > MAX_IMAGE_SIDE or width * height > MAX_IMAGE_PIXELS
    if width < 1 or height < 1 or too_big:
        raise InputError(
            f"{where}: image of {width}x{height} pixels; expected 1 to {MAX_IMAGE_SIDE} a side and at most "
            f"{MAX_IMAGE_PIXELS:,} pixels"
        )


def image_size(path: str | Path) -> tuple[int, int]:
    """(width, height) of an image file from its header, without decoding the pixels.

    Raises
    ------
    InputError
        If the file is missing, its header unreadable, or the size out of range
        (:func:`check_image_size`).
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: image file not found" + (" (it is a folder)" if path.is_dir() else ""))
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)  # our own limit applies below
            with Image.open(path) as im:
                width, height = im.size
    except Image.DecompressionBombError:
        raise InputError(f"{path}: image header declares more than {MAX_IMAGE_PIXELS:,} pixels") from None
    except (OSError, SyntaxError, ValueError) as exc:
        raise InputError(f"{path}: cannot decode image (corrupt or not an image: {exc}); "
                         "expected an 8-bit RGB image") from None
    check_image_size(width, height, path)
    return width, height


_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def check_png_structure(data: bytes | np.ndarray, path: str | Path) -> None:
    """Refuse a damaged PNG from its chunks: the signature, every chunk's length and CRC-32 (ISO/IEC
    15948 §5.3), and the closing IEND chunk (a truncated file has none). 1.4 ms for a 6 MB 1920x1080
    PNG, against 20 ms to read it.

    Raises
    ------
    InputError
        Naming the file and the first fault found.
    """
    # a view of the decoded file's bytes, not a copy: this runs on every frame read
    buf = np.ascontiguousarray(data, np.uint8).reshape(-1).data if isinstance(data, np.ndarray) else memoryview(data)
    if bytes(buf[:8]) != _PNG_SIGNATURE:
        raise InputError(f"{path}: not a PNG file (no PNG signature); expected an 8-bit RGB image")
    pos, n = 8, len(buf)
    while pos + 12 <= n:
        length, kind = struct.unpack(">I4s", buf[pos:pos + 8])
        end = pos + 12 + length
        if end > n:
            raise InputError(f"{path}: truncated PNG (chunk {kind.decode('latin-1')!r} runs past the end of the "
                             "file); expected a complete 8-bit RGB image")
        (crc,) = struct.unpack(">I", buf[end - 4:end])
        if zlib.crc32(buf[pos + 4:end - 4]) != crc:
            raise InputError(f"{path}: damaged PNG (CRC error in chunk {kind.decode('latin-1')!r} at byte {pos}); "
                             "expected an intact 8-bit RGB image")
        if kind == b"IEND":
            return
        pos = end
    raise InputError(f"{path}: truncated PNG (no IEND chunk); expected a complete 8-bit RGB image")


def check_video_container(path: str | Path) -> None:
    """Refuse an MP4/MOV whose top-level boxes (ISO/IEC 14496-12 §4.2) overrun the file or lack the
    ``moov`` index, as a truncated or damaged file does; other containers are left to the decoder.

    Raises
    ------
    InputError
        Naming the file and the fault.
    """
    path = Path(path)
    if path.suffix.lower() not in (".mp4", ".mov"):
        return
    size, pos, kinds = path.stat().st_size, 0, set()
    with open(path, "rb") as fh:
        while pos + 8 <= size:
            fh.seek(pos)
            head = fh.read(16)
            box, kind = struct.unpack(">I4s", head[:8])
            if box == 1 and len(head) == 16:
                box = struct.unpack(">Q", head[8:16])[0]
            elif box == 0:
                box = size - pos
            if box < 8 or pos + box > size or not kind.isascii():
                raise InputError(f"{path}: damaged or truncated video (box at byte {pos} runs past the end of the "
                                 "file); expected a complete mp4")
            kinds.add(kind)
            pos += box
    if b"moov" not in kinds:
        raise InputError(f"{path}: damaged or truncated video (no moov index); expected a complete mp4")


def read_rgb8(path: str | Path) -> np.ndarray:
    """Read an image file as uint8 RGB [H, W, 3].

    The header is read first, so a file declaring a huge size is refused before it is decoded.

    Raises
    ------
    InputError
        If the file is missing, corrupt, too large, grayscale, not 8-bit or has an alpha channel.
    """
    path = Path(path)
    width, height = image_size(path)
    data = np.fromfile(path, dtype=np.uint8)
    if data[:8].tobytes() == _PNG_SIGNATURE:
        check_png_structure(data, path)
    img = cv2.imdecode(data, cv2.IMREAD_UNCHANGED) if data.size else None
    img = _check_rgb8(img, path)
    if img.shape[:2] != (height, width):
        raise InputError(f"{path}: decodes to {img.shape[1]}x{img.shape[0]}, its header says {width}x{height}")
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


def to_float(img: np.ndarray, *, out: np.ndarray | None = None) -> np.ndarray:
    """uint8 RGB -> float32 RGB in [0, 1] (into ``out`` when given: same values to the bit)."""
    return np.multiply(img, np.float32(1.0 / 255.0), out=out, dtype=np.float32)


def to_uint8(img: np.ndarray) -> np.ndarray:
    """Float RGB in [0, 1] -> uint8 by ``round(255 x)``, clipped (exactly inverts :func:`to_float`).

    Parameters
    ----------
    img : ndarray [..., 3]
        Float in [0, 1], or uint8 (returned unchanged).
    """
    a = np.asarray(img)
    if a.dtype == np.uint8:
        return a
    # float32 arithmetic is exact here (k/255 * 255 lands within 1e-4 of k) and halves the memory
    # traffic of a full-HD frame; float64 input keeps float64.
    scaled = a * 255.0 if a.dtype == np.float64 else a.astype(np.float32, copy=False) * np.float32(255)
    np.rint(scaled, out=scaled)
    np.clip(scaled, 0, 255, out=scaled)
    return scaled.astype(np.uint8)


def write_png(path: str | Path, rgb: np.ndarray) -> None:
    """Write uint8 RGB [H, W, 3] (or float in [0, 1]) as PNG, atomically."""
    img = rgb if rgb.dtype == np.uint8 else to_uint8(rgb)
    if img.ndim != 3 or img.shape[2] != 3:
        raise ValueError(f"write_png: expected [H, W, 3], got {img.shape}")
    ok, buf = cv2.imencode(".png", cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
    if not ok:
        raise OSError(f"{path}: PNG encoding failed")
    atomic_write_bytes(path, buf.tobytes())


def resize_rgb8(img: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Resize uint8 RGB to (width, height): area filter when shrinking, bicubic when enlarging."""
    w, h = size
    shrink = w * h < img.shape[0] * img.shape[1]
    return cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA if shrink else cv2.INTER_CUBIC)


def read_mask(path: str | Path) -> np.ndarray:
    """Read an 8-bit single-channel mask image as bool [H, W] (set where the value is 128 or more).

    Raises
    ------
    InputError
        If the file is missing or does not decode.
    """
    data = np.fromfile(path, dtype=np.uint8) if Path(path).is_file() else np.zeros(0, np.uint8)
    img = cv2.imdecode(data, cv2.IMREAD_GRAYSCALE) if data.size else None
    if img is None:
        raise InputError(f"{path}: missing or not an image; expected an 8-bit mask (255 where set)")
    mask: np.ndarray = img >= 128
    return mask


def resize_mask(mask: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Resize a bool mask [H, W] to (width, height): a target pixel is set when any share of the
    source pixels it covers is set (area filter, then > 0), so a region never shrinks away."""
    area = cv2.resize(mask.astype(np.float32), size, interpolation=cv2.INTER_AREA if
                      size[0] * size[1] < mask.size else cv2.INTER_NEAREST)
    out: np.ndarray = area > 0
    return out


def video_frame_count(path: Path) -> int:
    """Number of decodable frames of a video (decodes it: container counts can lie)."""
    return sum(1 for _ in iter_video_rgb8(path))


def iter_video_rgb8(path: str | Path) -> Iterator[np.ndarray]:
    """Decode a video file frame by frame as uint8 RGB [H, W, 3].

    Raises
    ------
    InputError
        If the file is missing or OpenCV cannot open or decode it.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: video file not found")
    check_video_container(path)
    cap = cv2.VideoCapture(str(path))
    try:
        if not cap.isOpened():
            raise InputError(f"{path}: cannot open video (corrupt or unsupported codec); expected an mp4/avi file")
        check_image_size(int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT)), path)
        n = 0
        while True:
            ok, frame = cap.read()
            if not ok:
                break
            n += 1
            yield cv2.cvtColor(_check_rgb8(frame, path), cv2.COLOR_BGR2RGB)
        if n == 0:
            raise InputError(f"{path}: video has no decodable frames")
    finally:
        cap.release()


def write_mp4(path: str | Path, frames: list[np.ndarray], *, fps: float = 10.0) -> None:
    """Write uint8 RGB frames [H, W, 3] as an mp4 (mp4v codec), atomically."""
    if not frames:
        raise ValueError("write_mp4: no frames")
    h, w = frames[0].shape[:2]
    with atomic_path(path, suffix=".mp4") as tmp:
        writer = cv2.VideoWriter(str(tmp), cv2.VideoWriter.fourcc(*"mp4v"), fps, (w, h))
        if not writer.isOpened():
            raise OSError(f"{path}: OpenCV cannot write mp4 here")
        try:
            for f in frames:
                writer.write(cv2.cvtColor(f, cv2.COLOR_RGB2BGR))
        finally:
            writer.release()
