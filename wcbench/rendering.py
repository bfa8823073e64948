"""Render a runnable method's predictions into the canonical layout (the first half of ``run``)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from wcbench.errors import InputError
from wcbench.methods import Method, is_runnable
from wcbench.scene import SceneRef


def render_predictions(
    method: Method,
    scenes: list[SceneRef],
    weathers: list[str],
    out_root: Path,
    *,
    seed: int = 0,
    overwrite: bool = False,
    show_progress: bool = True,
) -> list[dict[str, Any]]:
    """Render every (scene, weather) into ``out_root/<scene>/<weather>/`` (resumable).

    Returns
    -------
    list of dict
        The ``info.json`` of every (scene, weather) rendered or found up to date.

    Raises
    ------
    InputError
        If ``method`` is an output reader (wcbench cannot run it).
    """
    if not is_runnable(method):
        raise InputError(
            f"method {method.info.name!r} is an output reader: wcbench cannot run it. Render with the tool "
            f"itself, then score its frames with `wcbench evaluate --method {method.info.name} --predictions DIR`"
        )
    infos = []
    for ref in scenes:
        scene = ref.load()
        for weather in weathers:
            infos.append(method.render(scene, weather, out_root / scene.id / weather,  # type: ignore[attr-defined]
                                       seed=seed, overwrite=overwrite, show_progress=show_progress))
    return infos
