"""CLIP-S and CLIP-DS (docs/design.md §5): functional forms and the metric classes built on them (torch-free).

With f the CLIP image encoder and g the text encoder, both L2-normalised:

- CLIP-S = cos(f(I), f(Î)): raw cosine (not x100, not clipped at 0) of the source frame I and
  the edited frame Î; content preservation, so skipped in fog (paper's rule).
- CLIP-DS, paper form = cos(f(Î) - f(I), g(T)) with T the target weather text;
  instruct-pix2pix ("directional") form = cos(f(Î) - f(I), g(T) - g(T_src)) with T_src the
  source text. Both are reported, as separate outputs. When the image delta vanishes
  (``|f(Î) - f(I)| < 1e-6``, i.e. an unedited frame up to float32 noise) the cosine is undefined:
  the frame scores 0.0 and is counted in ``extra["degenerate"]``.

Texts come from ``weather_prompts.toml`` (or a user file). Frames are embedded through a
:class:`~wcbench.metrics.clip.encoder.ClipEncoder`, so a source frame is embedded once however
many methods and metrics score it.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from wcbench.core.models.store import ModelStore, StoreBacked
from wcbench.core.options import Option, OptionError, Range
from wcbench.core.storage import sha256_file
from wcbench.metrics.base import (
    Metric,
    MetricContext,
    MetricValue,
    check_same_shape,
    finite_or_none,
    python_object_option,
)
from wcbench.metrics.clip.encoder import BACKENDS, DEFAULT_MODEL, ClipEmbedder, shared_clip_encoder
from wcbench.metrics.clip.preprocess import CROPS, ClipPreprocess
from wcbench.metrics.clip.tokenizer import VOCAB_ENTRY

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - exercised on Python 3.10 only
    import tomli as tomllib

DEFAULT_PROMPTS = Path(__file__).with_name("weather_prompts.toml")
FORMS = ("paper", "directional")
#: Below this norm of f(Î) - f(I) (unit vectors, float32 embeddings: noise is ~1e-7) the image
#: direction is treated as zero.
DEGENERATE_NORM = 1e-6
_VARIANT_S = "raw cosine of L2-normalised CLIP image embeddings of source and edited frame"
_VARIANT_DS = {
    "paper": "paper form cos(f(edit) - f(source), g(T_target)), f/g L2-normalised; zero image delta -> 0.0",
    "directional": (
        "instruct-pix2pix form cos(f(edit) - f(source), g(T_target) - g(T_source)), f/g L2-normalised; "
        "zero image delta -> 0.0"
    ),
}


@dataclass(frozen=True)
class WeatherPrompt:
    """CLIP-DS texts of one weather: ``target`` describes the edit, ``source`` the raw frame."""

    weather: str
    target: str
    source: str


def load_weather_prompts(path: str | os.PathLike[str] | None = None) -> dict[str, WeatherPrompt]:
    """Read CLIP-DS texts.

    Parameters
    ----------
    path : path-like, optional
        A TOML file with one ``[weather]`` table per weather holding ``target`` and ``source``
        strings; default the built-in ``weather_prompts.toml``.

    Raises
    ------
    ValueError
        If a table lacks a text, a text is empty, or target equals source (the direction
        g(T) - g(T_src) would vanish); the message names the file and weather.
    """
    path = Path(path) if path is not None else DEFAULT_PROMPTS
    with open(path, "rb") as fh:
        data = tomllib.load(fh)
    out = {}
    for weather, table in data.items():
        if not isinstance(table, Mapping):
            raise ValueError(f"{path}: {weather!r} must be a table with 'target' and 'source'")
        texts = {k: table.get(k) for k in ("target", "source")}
        for key, text in texts.items():
            if not isinstance(text, str) or not text.strip():
                raise ValueError(f"{path} [{weather}]: {key!r} must be a non-empty string")
        if texts["target"].strip() == texts["source"].strip():  # type: ignore[union-attr]
            raise ValueError(f"{path} [{weather}]: target and source texts must differ")
        out[weather] = WeatherPrompt(weather, str(texts["target"]), str(texts["source"]))
    return out


def clip_s_per_frame(f_src: np.ndarray, f_edit: np.ndarray) -> np.ndarray:
    """CLIP-S per frame: cosine of unit embeddings [B, E] x [B, E] -> [B] float64."""
    return np.einsum("be,be->b", np.asarray(f_src, np.float64), np.asarray(f_edit, np.float64))


def clip_ds_per_frame(
    f_src: np.ndarray, f_edit: np.ndarray, direction: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """CLIP-DS per frame, cos(f_edit - f_src, direction), and a mask of degenerate (zero-delta) frames.

    Parameters
    ----------
    f_src, f_edit : ndarray [B, E]
        Unit image embeddings.
    direction : ndarray [E]
        Text direction (need not be unit).

    Returns
    -------
    values : ndarray [B] float64
        Cosines; 0.0 where the image delta vanishes.
    degenerate : ndarray [B] bool
    """
    delta = np.asarray(f_edit, np.float64) - np.asarray(f_src, np.float64)
    d = np.asarray(direction, np.float64)
    dn = np.linalg.norm(d)
    if not dn > 0:
        raise ValueError("the text direction is zero: target and source texts embed identically")
    norms = np.linalg.norm(delta, axis=1)
    degenerate = norms < DEGENERATE_NORM
    values = np.zeros(len(delta))
    ok = ~degenerate
    values[ok] = (delta[ok] @ d) / (norms[ok] * dn)
    return values, degenerate


def text_directions(
    embedder: ClipEmbedder, prompt: WeatherPrompt, where: str | os.PathLike[str] = ""
) -> dict[str, np.ndarray]:
    """The text directions of both CLIP-DS forms: ``{"paper": g(T), "directional": g(T) - g(T_src)}`` [E].

    Raises
    ------
    ValueError
        If a text is longer than CLIP's 77 tokens (the message names ``where`` and the weather).
    """
    try:
        target, source = embedder.text_embeddings([prompt.target, prompt.source])
    except ValueError as exc:
        raise ValueError(f"{where} [{prompt.weather}]: {exc}") from exc
    return {"paper": target, "directional": target - source}


def _summary(values: list[float], *, variant: str, extra: dict[str, Any]) -> MetricValue:
    if not values:
        return MetricValue(value=None, reason="no frames were scored", variant=variant, extra=extra)
    return MetricValue.from_number(
        float(np.mean(values)),
        nonfinite_reason="non-finite CLIP embedding",
        per_frame=finite_or_none(values),
        variant=variant,
        extra=extra,
    )


def _frames(x: np.ndarray | None, name: str) -> np.ndarray:
    if x is None:
        raise ValueError(f"{name} frames are required (CLIP metrics compare the edit with its source)")
    a = np.asarray(x)
    return a[None] if a.ndim == 3 else a


def _model_option(value: Any) -> str:
    """A ``model`` option's value: a name (whether the catalogue has it is :meth:`_ClipMetric.check_options`'s)."""
    if isinstance(value, str) and value:
        return value
    raise ValueError("expected a CLIP model of the catalogue (`wcbench models list`), e.g. " + DEFAULT_MODEL)


def _weather_option(value: Any) -> str:
    """A ``weather`` option's value: a name (whether the prompts file has it is
    :meth:`ClipDirectionalScore.check_options`'s)."""
    if isinstance(value, str) and value:
        return value
    raise ValueError("expected a weather of the prompts file, e.g. rain")


def _prompts_option(value: Any) -> str | os.PathLike[str]:
    """A ``prompts`` option's value: a readable texts file (:func:`load_weather_prompts` takes it)."""
    if not isinstance(value, (str, os.PathLike)) or not str(value):
        raise ValueError("expected a path to a TOML file of weather texts (as weather_prompts.toml)")
    try:
        load_weather_prompts(value)
    except (OSError, tomllib.TOMLDecodeError) as exc:
        raise ValueError(f"expected a readable TOML file of weather texts: {exc}") from None
    return value  # a ValueError of load_weather_prompts names the file and the text at fault


class _ClipMetric(StoreBacked, Metric):
    """Shared set-up of the CLIP metrics: which model, which embedder, which preprocessing."""

    higher_is_better: ClassVar[bool] = True
    needs_texts: ClassVar[bool] = False
    OPTIONS: ClassVar[dict[str, Option] | None] = {
        "model": Option("model", "custom", "CLIP model of the model store", default=DEFAULT_MODEL,
                        check=_model_option, allowed="a CLIP model of the catalogue (`wcbench models list`)"),
        "embedder": python_object_option("embedder", "injected embedder in place of the model (tests, custom "
                                         "models)", accepts=lambda v: isinstance(v, ClipEmbedder),
                                         what="a ClipEmbedder"),
        "store": python_object_option("store", "model store the weights are read from (default $WCBENCH_MODELS)",
                                      accepts=lambda v: isinstance(v, ModelStore), what="a ModelStore"),
        "backend": Option("backend", "str", "how the model runs: onnx (onnxruntime), torch (needs the [model] "
                          "extra)", default="onnx", choices=BACKENDS),
        "crop": Option("crop", "str", "center crops to CLIP's square as CLIP does (a 16:9 frame loses its sides), "
                       "squash keeps the whole frame", default="center", choices=CROPS),
        "batch_size": Option("batch_size", "int", "frames per inference call", default=16, range=Range(1)),
    }

    @classmethod
    def check_options(cls, options: Mapping[str, Any]) -> None:
        """A ``model`` given is an entry of the catalogue (of ``store`` when one is given), unless an
        ``embedder`` replaces it."""
        if "model" in options and options.get("embedder") is None:
            cls.check_model_option("model", options["model"], options.get("store"), example=DEFAULT_MODEL)

    def __init__(
        self,
        *,
        model: str = DEFAULT_MODEL,
        embedder: ClipEmbedder | None = None,
        store: ModelStore | None = None,
        backend: str = "onnx",
        crop: str = "center",
        batch_size: int = 16,
    ):
        ClipPreprocess(crop=crop)  # validates crop now, not at the first frame
        if backend not in BACKENDS:
            raise ValueError(f"backend must be one of {BACKENDS}, got {backend!r}")
        self.model = model
        self.backend = backend
        self.crop = crop
        self.batch_size = batch_size
        self._store = store
        self._embedder = embedder
        self.reset()

    @property
    def embedder(self) -> ClipEmbedder:
        """The injected embedder or the process-wide shared encoder of ``model`` (loaded on first use)."""
        if self._embedder is None:
            self._embedder = shared_clip_encoder(
                self.model, store=self.store, backend=self.backend, crop=self.crop, batch_size=self.batch_size
            )
        return self._embedder

    def _image_embeddings(self, pred: np.ndarray, source: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """Unit image embeddings ``(f(source), f(pred))`` [B, E] of a batch (ValueError: no source, or
        shapes that differ)."""
        edit, src = _frames(pred, "pred"), _frames(source, "source")
        check_same_shape(edit, src, names=("pred", "source"))
        emb = self.embedder
        return emb.image_embeddings(src), emb.image_embeddings(edit)

    def skip_reason(self, ctx: MetricContext) -> str | None:
        """Base rules, then: source frames needed, weights (and vocabulary) installed."""
        reason = super().skip_reason(ctx)
        if reason is not None:
            return reason
        if not ctx.has_source:
            return "needs the source (raw) frames, which this scene lacks"
        if self._embedder is None:
            for name in (self.model, VOCAB_ENTRY) if self.needs_texts else (self.model,):
                missing = self.store.missing_reason(name)
                if missing is not None:
                    return missing
        return None

    def required_models(self) -> tuple[str, ...]:
        """The CLIP entry (and the BPE vocabulary where texts are encoded), unless an embedder was injected."""
        if self._embedder is not None:
            return ()
        return (self.model, VOCAB_ENTRY) if self.needs_texts else (self.model,)

    def config(self) -> dict[str, Any]:
        """Model, weights hash, backend and preprocessing (crop choice included)."""
        if self._embedder is not None:
            return dict(self._embedder.config())
        return {
            "model": self.model,
            "backend": self.backend,
            "weights_sha256": self.store.sha256(self.model),
            "weights_verified": self.store.source_verified(self.model),
            "preprocess": ClipPreprocess(crop=self.crop).config(),
        }


class ClipScore(_ClipMetric):
    """CLIP-S = cos(f(I), f(Î)), mean over frames (see module docstring).

    Parameters
    ----------
    model : str
        Model-store entry (default ``"clip-vit-b32-openai"``).
    embedder : ClipEmbedder, optional
        Injected embedder (tests, custom models); then ``model``/``store``/``backend`` are unused.
    store : ModelStore, optional
    backend : str
        ``"onnx"`` (default, no torch) or ``"torch"``.
    crop : str
        ``"center"`` (CLIP's; a 16:9 frame loses its sides) or ``"squash"``.
    batch_size : int
        Frames per inference call.
    """

    name: ClassVar[str] = "clip_s"
    description: ClassVar[str] = "CLIP-S: cosine of CLIP image embeddings of source and edited frame"
    outputs: ClassVar[tuple[str, ...]] = ("clip_s",)
    compares_content: ClassVar[bool] = True

    def reset(self) -> None:
        """Forget the per-frame values."""
        self._values: list[float] = []

    def update(
        self, pred: np.ndarray, *, source: np.ndarray | None = None, reference: np.ndarray | None = None
    ) -> None:
        """Score a batch: ``pred`` [B, H, W, 3] edited frames against ``source`` [B, H, W, 3], RGB in [0, 1].

        Raises
        ------
        ValueError
            If ``source`` is missing or the shapes differ (both shapes named).
        """
        self._values.extend(clip_s_per_frame(*self._image_embeddings(pred, source)).tolist())

    def compute(self) -> dict[str, MetricValue]:
        """``{"clip_s": mean over frames, per-frame values}``."""
        return {"clip_s": _summary(self._values, variant=_VARIANT_S, extra={})}


class ClipDirectionalScore(_ClipMetric):
    """CLIP-DS in both forms, mean over frames (see module docstring).

    Outputs ``"clip_ds"`` (paper form) and ``"clip_ds_directional"`` (instruct-pix2pix form); each
    carries ``extra["degenerate"]``, the number of frames whose image delta vanished (scored 0.0),
    and the texts used.

    The weather picks the texts. Pass ``weather`` here, or let :meth:`bind` take it from the
    :class:`MetricContext` of each sequence (the evaluation runner binds before every sequence).

    Parameters
    ----------
    weather : str, optional
        ``"rain"``, ``"snow"``, ``"fog"`` (any weather of the prompts file).
    prompts : path-like, optional
        Texts file (default: the built-in ``weather_prompts.toml``).
    model, embedder, store, backend, crop, batch_size
        As :class:`ClipScore`.
    """

    name: ClassVar[str] = "clip_ds"
    description: ClassVar[str] = "CLIP-DS: alignment of the CLIP image edit direction with the weather text"
    outputs: ClassVar[tuple[str, ...]] = ("clip_ds", "clip_ds_directional")
    needs_texts: ClassVar[bool] = True
    OPTIONS: ClassVar[dict[str, Option] | None] = {
        "weather": Option("weather", "custom", "weather whose texts every sequence is scored with; null: each "
                          "sequence's own", nullable=True, check=_weather_option,
                          allowed="a weather of the prompts file, e.g. rain"),
        "prompts": Option("prompts", "custom", "TOML file of the texts of each weather; null: the built-in "
                          "weather_prompts.toml", nullable=True, check=_prompts_option,
                          allowed="a path to a TOML file of weather texts"),
        **(_ClipMetric.OPTIONS or {}),
    }

    @classmethod
    def check_options(cls, options: Mapping[str, Any]) -> None:
        """As :class:`ClipScore`, and a ``weather`` given has texts in the prompts file."""
        super().check_options(options)
        weather = options.get("weather")
        if weather is not None:
            path = options.get("prompts")
            known = load_weather_prompts(path)
            if weather not in known:
                where = path if path is not None else f"the built-in {DEFAULT_PROMPTS.name}"
                raise OptionError(f"expected a weather of {where}: {', '.join(known)}", path="weather")

    def __init__(
        self,
        *,
        weather: str | None = None,
        prompts: str | os.PathLike[str] | None = None,
        model: str = DEFAULT_MODEL,
        embedder: ClipEmbedder | None = None,
        store: ModelStore | None = None,
        backend: str = "onnx",
        crop: str = "center",
        batch_size: int = 16,
    ):
        self.prompts_path = Path(prompts) if prompts is not None else DEFAULT_PROMPTS
        self.prompts = load_weather_prompts(self.prompts_path)
        self._fixed_weather = weather
        self.weather = weather
        if weather is not None:
            self._prompt(weather)
        self._directions: dict[str, dict[str, np.ndarray]] = {}
        super().__init__(
            model=model, embedder=embedder, store=store, backend=backend, crop=crop, batch_size=batch_size
        )

    def _prompt(self, weather: str) -> WeatherPrompt:
        if weather not in self.prompts:
            raise ValueError(
                f"no CLIP-DS texts for weather {weather!r} in {self.prompts_path} "
                f"(it has {', '.join(self.prompts)})"
            )
        return self.prompts[weather]

    def bind(self, ctx: MetricContext) -> None:
        """Take the weather (and so the texts) from ``ctx`` unless one was fixed at construction."""
        if self._fixed_weather is None and ctx.weather != self.weather:
            self.weather = ctx.weather
            self.reset()

    def skip_reason(self, ctx: MetricContext) -> str | None:
        """Skip on clear (no edit, no text direction) and on weathers without texts."""
        if ctx.weather == "clear":
            return "clear: no weather edit, so there is no target text direction to compare with"
        if ctx.weather not in self.prompts:
            return f"no CLIP-DS texts for weather {ctx.weather!r} in {self.prompts_path}"
        return super().skip_reason(ctx)

    def config(self) -> dict[str, Any]:
        """As :class:`ClipScore` plus the texts file (path, sha256) and the texts of the bound weather."""
        cfg = super().config()
        cfg["prompts_file"] = str(self.prompts_path)
        cfg["prompts_sha256"] = sha256_file(self.prompts_path)  # edited texts invalidate cached scores
        if self.weather is not None:
            p = self._prompt(self.weather)
            cfg["texts"] = {"weather": p.weather, "target": p.target, "source": p.source}
        return cfg

    def reset(self) -> None:
        """Forget the per-frame values and degenerate counts."""
        self._values: dict[str, list[float]] = {form: [] for form in FORMS}
        self._degenerate = 0

    def _direction(self, weather: str) -> dict[str, np.ndarray]:
        if weather not in self._directions:
            self._directions[weather] = text_directions(self.embedder, self._prompt(weather), self.prompts_path)
        return self._directions[weather]

    def update(
        self, pred: np.ndarray, *, source: np.ndarray | None = None, reference: np.ndarray | None = None
    ) -> None:
        """Score a batch: ``pred`` [B, H, W, 3] edited frames against ``source`` [B, H, W, 3], RGB in [0, 1].

        Raises
        ------
        ValueError
            If no weather is bound, ``source`` is missing, or the shapes differ.
        """
        if self.weather is None:
            raise ValueError("clip_ds: no weather bound (pass weather= or call bind(ctx) first)")
        f_src, f_edit = self._image_embeddings(pred, source)
        directions = self._direction(self.weather)
        for form in FORMS:
            values, degenerate = clip_ds_per_frame(f_src, f_edit, directions[form])
            self._values[form].extend(values.tolist())
        self._degenerate += int(degenerate.sum())

    def compute(self) -> dict[str, MetricValue]:
        """``{"clip_ds": paper form, "clip_ds_directional": instruct-pix2pix form}``."""
        extra: dict[str, Any] = {"degenerate": self._degenerate}
        if self.weather is not None:
            p = self._prompt(self.weather)
            extra.update(weather=p.weather, target_text=p.target, source_text=p.source)
        return {
            "clip_ds": _summary(self._values["paper"], variant=_VARIANT_DS["paper"], extra=dict(extra)),
            "clip_ds_directional": _summary(
                self._values["directional"], variant=_VARIANT_DS["directional"], extra=dict(extra)
            ),
        }


def _resolve(model: str | ClipEmbedder, store: ModelStore | None, backend: str, crop: str) -> ClipEmbedder:
    if isinstance(model, str):
        return shared_clip_encoder(model, store=store, backend=backend, crop=crop)
    return model


def _pair(img0: np.ndarray, img1: np.ndarray, names: tuple[str, str]) -> tuple[np.ndarray, np.ndarray]:
    a, b = _frames(img0, names[0]), _frames(img1, names[1])
    check_same_shape(a, b, names=names)
    if not len(a):
        raise ValueError("no score: no frames were scored")
    return a, b


def _mean_or_raise(values: np.ndarray) -> float:
    value = float(np.mean(values))
    if not np.isfinite(value):
        raise ValueError(f"no score: non-finite CLIP embedding (value was {value})")
    return value


def clip_s(
    img0: np.ndarray,
    img1: np.ndarray,
    *,
    model: str | ClipEmbedder = DEFAULT_MODEL,
    store: ModelStore | None = None,
    backend: str = "onnx",
    crop: str = "center",
) -> float:
    """CLIP-S = cos(f(img0), f(img1)), mean over frames; :class:`ClipScore` accumulates the same values.

    Parameters
    ----------
    img0, img1 : ndarray [H, W, 3] or [B, H, W, 3]
        Source and edited frames, RGB float in [0, 1] (or uint8), same shape.
    model : str or ClipEmbedder
        Model-store entry (default ``"clip-vit-b32-openai"``) or an embedder object.
    store : ModelStore, optional
    backend : str
        ``"onnx"`` or ``"torch"`` (for a model name).
    crop : str
        ``"center"`` or ``"squash"``.

    Returns
    -------
    float
        Cosine in [-1, 1] (mean over the B frames of a batch).

    Raises
    ------
    ValueError
        On mismatched shapes, values outside [0, 1] or an empty batch.
    ModelMissingError
        If the weights are not installed.
    """
    src, edit = _pair(img0, img1, ("img0", "img1"))
    emb = _resolve(model, store, backend, crop)
    return _mean_or_raise(clip_s_per_frame(emb.image_embeddings(src), emb.image_embeddings(edit)))


def clip_ds(
    src: np.ndarray,
    edit: np.ndarray,
    weather: str,
    *,
    model: str | ClipEmbedder = DEFAULT_MODEL,
    form: str = "paper",
    prompts: str | os.PathLike[str] | None = None,
    store: ModelStore | None = None,
    backend: str = "onnx",
    crop: str = "center",
) -> float:
    """CLIP-DS of an edit, mean over frames; :class:`ClipDirectionalScore` accumulates the same values.

    Parameters
    ----------
    src, edit : ndarray [H, W, 3] or [B, H, W, 3]
        Source and edited frames, RGB float in [0, 1] (or uint8), same shape.
    weather : str
        Picks the texts in the prompts file (``"rain"``, ``"snow"``, ``"fog"``...).
    model : str or ClipEmbedder
        Model-store entry or an embedder object.
    form : str
        ``"paper"``: cos(f(edit) - f(src), g(T)); ``"directional"``: cos(f(edit) - f(src),
        g(T) - g(T_src)) (instruct-pix2pix).
    prompts : path-like, optional
        Texts file (default the built-in one).
    store, backend, crop
        As :func:`clip_s`.

    Returns
    -------
    float
        Cosine in [-1, 1] (mean over frames); 0.0 for a frame whose image embedding did not move.

    Raises
    ------
    ValueError
        On an unknown form or weather, mismatched shapes, an empty batch, or a text longer than
        77 tokens.
    """
    if form not in FORMS:
        raise ValueError(f"form must be one of {FORMS}, got {form!r}")
    path = Path(prompts) if prompts is not None else DEFAULT_PROMPTS
    texts = load_weather_prompts(path)
    if weather not in texts:
        raise ValueError(f"no CLIP-DS texts for weather {weather!r} in {path} (it has {', '.join(texts)})")
    s, e = _pair(src, edit, ("source", "pred"))
    emb = _resolve(model, store, backend, crop)
    direction = text_directions(emb, texts[weather], path)[form]
    values, _ = clip_ds_per_frame(emb.image_embeddings(s), emb.image_embeddings(e), direction)
    return _mean_or_raise(values)
