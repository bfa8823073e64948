"""Pictures of the report: frame strips and animations (Pillow), curves and charts (matplotlib).

Everything is returned as bytes to inline as ``data:`` URIs. Frames are read from the paths the
results record and shown only when their sha256 equals the recorded one, so a picture is always
of the frames that were scored. Output is deterministic for the same inputs and library versions.
"""

from __future__ import annotations

import base64
import io
import math
import os
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from PIL import Image, UnidentifiedImageError

from .loading import read_checked_file

#: Largest size of an animation frame (px) and its frame count: enough to see flicker, small
#: enough that 48 sequences stay well inside the report's size budget.
ANIMATION_SIZE = (320, 180)
ANIMATION_FRAMES = 12
ANIMATION_MS_PER_FRAME = 100
#: Strip thumbnails: large enough to judge an edit, at JPEG quality that keeps rain streaks.
STRIP_SIZE = (480, 270)
JPEG_QUALITY = 85
WEBP_QUALITY = 70
_IO_THREADS = max(1, min(4, os.cpu_count() or 1))


@dataclass(frozen=True)
class Picture:
    """An encoded image to inline: bytes, MIME type and pixel size."""

    data: bytes
    mime: str
    width: int
    height: int

    @property
    def uri(self) -> str:
        """``data:`` URI of the image."""
        return f"data:{self.mime};base64,{base64.b64encode(self.data).decode('ascii')}"


@dataclass(frozen=True)
class FrameRef:
    """A frame file to show, with the sha256 the results recorded for it."""

    path: Path
    sha256: str | None


def load_frame(ref: FrameRef, max_size: tuple[int, int]) -> tuple[Image.Image | None, str]:
    """The frame as RGB, shrunk to fit ``max_size`` (w, h), or ``None`` and why not.

    The bytes are hashed and decoded from one read, so the picture is the checked file.
    """
    if ref.path.suffix.lower() not in (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp"):
        return None, f"{ref.path.name}: frames inside a video are not shown"
    data, why = read_checked_file(ref.path, ref.sha256)
    if data is None:
        return None, why
    try:
        opened = Image.open(io.BytesIO(data))
        opened.draft("RGB", max_size)  # JPEG: decode at a reduced scale directly
        img = opened.convert("RGB")
    except (UnidentifiedImageError, OSError) as exc:
        return None, f"{ref.path}: cannot decode ({exc})"
    img.thumbnail(max_size, Image.Resampling.LANCZOS, reducing_gap=2.0)
    return img, ""


def load_frames(refs: Sequence[FrameRef], max_size: tuple[int, int]) -> list[tuple[Image.Image | None, str]]:
    """:func:`load_frame` for many frames on a few threads (decoding and hashing release the GIL)."""
    if len(refs) <= 1:
        return [load_frame(r, max_size) for r in refs]
    with ThreadPoolExecutor(_IO_THREADS) as pool:
        return list(pool.map(lambda r: load_frame(r, max_size), refs))


def jpeg(img: Image.Image) -> Picture:
    """A still frame as JPEG."""
    buf = io.BytesIO()
    img.save(buf, format="JPEG", quality=JPEG_QUALITY, optimize=True)
    return Picture(buf.getvalue(), "image/jpeg", *img.size)


def animation(frames: Sequence[Image.Image], *, ms_per_frame: int = ANIMATION_MS_PER_FRAME) -> Picture:
    """Frames (at most :data:`ANIMATION_SIZE`) as a looping animated WebP, or GIF when Pillow lacks WebP.

    Raises
    ------
    ValueError
        On no frames or frames larger than :data:`ANIMATION_SIZE`.
    """
    if not frames:
        raise ValueError("an animation needs at least one frame")
    size = frames[0].size
    if size[0] > ANIMATION_SIZE[0] or size[1] > ANIMATION_SIZE[1] or any(f.size != size for f in frames):
        sizes = sorted({f.size for f in frames})
        raise ValueError(f"animation frames must share one size within {ANIMATION_SIZE}, got {sizes}")
    buf = io.BytesIO()
    try:
        frames[0].save(buf, format="WEBP", save_all=True, append_images=list(frames[1:]), duration=ms_per_frame,
                       loop=0, quality=WEBP_QUALITY, method=4)
        return Picture(buf.getvalue(), "image/webp", *size)
    except (KeyError, OSError, ValueError):  # Pillow built without WebP
        buf = io.BytesIO()
        pal = [f.convert("P", palette=Image.Palette.ADAPTIVE) for f in frames]
        pal[0].save(buf, format="GIF", save_all=True, append_images=pal[1:], duration=ms_per_frame, loop=0)
        return Picture(buf.getvalue(), "image/gif", *size)


def animation_indices(n_frames: int, count: int = ANIMATION_FRAMES) -> list[int]:
    """Consecutive frame indices from the middle of the sequence (flicker shows between neighbours)."""
    count = max(0, min(count, n_frames))
    start = max(0, (n_frames - count) // 2)
    return list(range(start, start + count))


# -- charts ---------------------------------------------------------------------------------------

_COLORS = ("#1f77b4", "#d62728", "#2ca02c", "#ff7f0e", "#9467bd", "#8c564b", "#e377c2", "#17becf", "#7f7f7f")


def method_color(index: int) -> str:
    """A fixed color per method position (the same in every chart)."""
    return _COLORS[index % len(_COLORS)]


def _png(fig: Any) -> Picture:
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    canvas = FigureCanvasAgg(fig)
    buf = io.BytesIO()
    canvas.print_png(buf, metadata={"Software": None})  # no version string: same bytes across builds
    w, h = canvas.get_width_height()
    return Picture(buf.getvalue(), "image/png", int(w), int(h))


def per_frame_figure(
    series: dict[str, dict[str, list[float | None]]],
    *,
    labels: dict[str, str],
    colors: dict[str, str],
) -> Picture:
    """Small multiples of per-frame values: one panel per output, one line per method.

    Parameters
    ----------
    series : dict
        ``{output: {method: per-frame values}}`` (``None`` = not a finite number, drawn as a gap).
    labels : dict
        Panel titles per output (label and arrow).
    colors : dict
        Line color per method.

    Raises
    ------
    ValueError
        When no output has a finite value.
    """
    from matplotlib.figure import Figure

    series = {o: by_method for o, by_method in series.items()
              if any(v is not None for values in by_method.values() for v in values)}
    if not series:
        raise ValueError("no finite per-frame value to draw")
    outputs = list(series)
    ncols = min(3, len(outputs))
    nrows = math.ceil(len(outputs) / ncols)
    height = 2.0 * nrows + 0.4
    # fixed margins: matplotlib's layout engines cost more than drawing these small panels
    fig = Figure(figsize=(3.3 * ncols, height), dpi=90)
    fig.subplots_adjust(left=0.08 if ncols > 1 else 0.18, right=0.98, top=1 - 0.62 / height, bottom=0.42 / height,
                        hspace=0.9 / 2.0, wspace=0.3)
    axes = fig.subplots(nrows, ncols, squeeze=False)
    for ax, output in zip(axes.flat, outputs):
        for method, values in series[output].items():
            ys = [math.nan if v is None else float(v) for v in values]
            ax.plot(range(len(ys)), ys, color=colors[method], lw=1.3, marker="." if len(ys) < 40 else None,
                    label=method)
        ax.set_title(labels.get(output, output), fontsize=9)
        ax.tick_params(labelsize=7)
        ax.ticklabel_format(axis="y", useOffset=False)  # a flat 1.0 series, not "1e-12 + 1"
        ax.grid(alpha=0.3)
    for ax in list(axes.flat)[len(outputs):]:
        ax.set_visible(False)
    handles, names = axes.flat[0].get_legend_handles_labels()
    fig.legend(handles, names, loc="upper center", ncols=min(6, max(1, len(names))), fontsize=8, frameon=False)
    return _png(fig)


def bench_figure(cases: list[dict[str, Any]], *, knob: str, suite: str,
                 front: Sequence[bool] | None = None) -> Picture | None:
    """Time (ms) against error of the cases of one knob; cases with ``"default": true`` starred, and
    the cases flagged in ``front`` (one flag per case with a time and an error) joined by a line.

    Returns ``None`` when no case has both a time and an error.
    """
    from matplotlib.figure import Figure

    pts = [c for c in cases if isinstance(c.get("time_ms"), (int, float)) and isinstance(c.get("error"), (int, float))]
    if not pts:
        return None
    fig = Figure(figsize=(5.2, 3.4), dpi=90)
    fig.subplots_adjust(left=0.14, right=0.97, top=0.9, bottom=0.14)
    ax = fig.subplots()
    xs = [float(c["time_ms"]) for c in pts]
    ys = [float(c["error"]) for c in pts]
    ax.scatter(xs, ys, color=_COLORS[0], s=28, zorder=3)
    if front is not None:
        line = sorted((x, y) for x, y, f in zip(xs, ys, front) if f)
        if len(line) > 1:
            ax.plot([p[0] for p in line], [p[1] for p in line], color=_COLORS[0], alpha=0.5, lw=1, zorder=2,
                    label="Pareto front")
            ax.legend(fontsize=7, frameon=False)
    for c, x, y in zip(pts, xs, ys):
        default = c.get("default") is True
        if default:
            ax.scatter([x], [y], marker="*", s=220, facecolor="none", edgecolor=_COLORS[1], lw=1.5, zorder=4)
        ax.annotate(f"{c.get('value')}" + (" (default)" if default else ""), (x, y), textcoords="offset points",
                    xytext=(5, 4), fontsize=7, color=_COLORS[1] if default else "#333")
    for axis, vals in (("x", xs), ("y", ys)):
        pos = [v for v in vals if v > 0]
        if len(pos) == len(vals) and len(pos) > 1 and max(pos) / min(pos) > 20:
            (ax.set_xscale if axis == "x" else ax.set_yscale)("log")
    unit = pts[0].get("error_unit", "")
    ax.set_xlabel("time (ms)", fontsize=8)
    ax.set_ylabel(f"error ({unit})", fontsize=8)
    ax.tick_params(labelsize=7)
    ax.grid(alpha=0.3)
    ax.set_title(f"{suite}: {knob}", fontsize=9)
    return _png(fig)
