"""The method adapter protocol shared by runnable methods and output readers.

Render and evaluate meet only at the on-disk prediction layout (docs/design.md §4)::

    <root>/<scene>/<weather>/{frame:03d}.png     # one PNG per frame, uint8 sRGB
    <root>/<scene>/<weather>/info.json           # method, version, parameters, timings, hashes

A *runnable* method writes that layout (:meth:`RunnableMethod.render`); an *output reader* maps
another tool's files onto frames (:meth:`Method.open_predictions`). Both return a
:class:`~wcbench.predictions.PredictionSequence`, so the evaluator never knows which it has.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

if TYPE_CHECKING:
    from wcbench.predictions import PredictionSequence
    from wcbench.scenes.scene import Scene



@dataclass(frozen=True)
class MethodInfo:
    """What a method is and what it can produce, known before any work starts.

    Attributes
    ----------
    name : str
        Registry name.
    description : str
        One line for ``wcbench methods list``.
    kind : {"runnable", "reader"}
        Whether wcbench runs it or only reads its outputs.
    weathers : tuple of str
        Weathers it supports (subset of :data:`wcbench.core.weathers.WEATHERS`).
    outputs : tuple of str
        What it produces per frame (``"rgb"``; later ``"depth"``...).
    layout : str
        The file layout and naming it reads or writes (shown by ``wcbench methods list -v``).
    defaults : dict
        A reader's naming settings (patterns, frame numbering...), recorded with results.
    edits_source : bool
        The tool edits the source frames (an image or video editor): when its frames of a weather
        other than ``clear`` all equal the source frames, evaluation warns that ``--predictions``
        likely points at the tool's copy of its input.
    unedited_hint : str
        Appended to that warning (which of the tool's folders holds its input).
    scene_folders : tuple of str
        Extra patterns for the folder of a scene, ``{scene}`` standing for any name the scene set
        gives it and ``*`` for any text (``"{scene}_*"`` for run folders named ``788_1_cam_000_029``).
    requires : tuple of str
        What rendering needs besides the evaluation side (``"torch"``: the ``[model]`` extra); a
        distributed run only sends its render work to workers that declare these resources.
    """

    name: str
    description: str
    kind: str
    weathers: tuple[str, ...]
    outputs: tuple[str, ...] = ("rgb",)
    layout: str = ""
    defaults: dict[str, Any] = field(default_factory=dict)
    edits_source: bool = False
    unedited_hint: str = ""
    scene_folders: tuple[str, ...] = ()
    requires: tuple[str, ...] = ()


@runtime_checkable
class Method(Protocol):
    """Anything that yields a method's frames for a (scene, weather)."""

    info: MethodInfo

    def open_predictions(
        self, scene: Scene, weather: str, root: Path, *, pattern: str | None = None, resize: bool = False,
        frame_offset: int = 0, single_weather: bool = False, frames: Sequence[int] | None = None,
    ) -> PredictionSequence:
        """Map the files under ``root`` to the scene's frames for ``weather``.

        Parameters
        ----------
        pattern : str, optional
            Overrides the method's file naming (see :mod:`wcbench.predictions`).
        resize : bool
            Resize frames of another size to the scene's size.
        frame_offset : int
            The method's frame *i* is scene frame ``i + frame_offset``.
        single_weather : bool
            Only this weather is scored: its ``<weather>`` folder level may be left out.
        frames : sequence of int, optional
            Only these scene frames (a contiguous run) are scored; default: every frame.

        Raises
        ------
        PredictionsMissingError
            Nothing for this weather.
        InputError
            Missing or extra frames (all named), unreadable files, wrong sizes (unless ``resize``).
        """
        ...


@runtime_checkable
class RunnableMethod(Method, Protocol):
    """A method wcbench can run itself."""

    def check_scene(self, scene: Scene, weather: str) -> None:
        """Raise ``InputError`` if ``scene`` lacks what rendering ``weather`` needs (ground-truth
        frames...); called for every unit before anything is rendered."""
        ...

    def render(self, scene: Scene, weather: str, out_dir: Path, *, seed: int = 0,
               frames: Sequence[int] | None = None, overwrite: bool = False, video: bool = False,
               show_progress: bool = True) -> dict[str, Any]:
        """Render frames of ``scene`` under ``weather`` into ``out_dir`` (the prediction layout).

        ``frames`` selects frame indices (default all; each frame is a pure function of the seed
        and its index); ``video`` also writes ``<weather>.mp4`` beside ``out_dir``. Returns the
        ``info.json`` content (method, version, parameters, timings, hashes). A folder finished
        with other settings is kept unless ``overwrite``.
        """
        ...
