"""Procedural driving scenes with ground-truth weather: the ``synth_1`` and ``synth_3`` scene sets.

No public dataset shows the same street under true rain, snow and fog, so these scenes are built
from known content (docs/design.md §3): a street of 3D Gaussians (road with lane markings, raised
sidewalks, building facades with windows, trees, parked cars, moving cars and, in some scenes, a
walking pedestrian) seen by a camera driving at 8 m/s. Every frame, clear and each weather, is
rendered by the reference model's :class:`~wcbench.reference_model.weather.renderer.WeatherRenderer`
(docs/design.md §7). A weather first changes the materials (wet asphalt with a sky sheen and
puddles under rain, snow cover on upward-facing Gaussians, dimmer overcast light), then the rain
and snow particles and the fog come from the model's physics.

Each scene is written in drivestudio's Waymo layout, exactly as
:func:`wcbench.scenes.loaders.load_waymo_layout` reads it, with the truth beside it
(``truth/{weather}/{t:03d}_0.png`` and ``truth/weather.json``). Scenes are generated on first use
into the cache folder (``scenes/synth-v{VERSION}/synth_{k:03d}``), built in a temporary folder and
renamed into place; generation is seeded and byte-for-byte deterministic (PNG images, fixed text
formats).

Rendering needs the reference model (torch and numba, the ``[model]`` extra); a scene already in the
cache loads without it.

The package: :mod:`.layout` (constants, truth weathers and materials, the scenes of the sets),
:mod:`.geometry` (poses, the street centreline, surface Gaussians), :mod:`.content` (what a scene
holds), :mod:`.lidar` (ray casting of the sweeps), :mod:`.truth` (shading and rendering every
weather) and :mod:`.writer` (the dataset layout on disk and the cache).
"""

from __future__ import annotations

from wcbench.scenes.synth.content import build_content
from wcbench.scenes.synth.geometry import gaussian_normals
from wcbench.scenes.synth.layout import MATERIALS, SCENES, TRUTH_WEATHERS, VERSION, SynthSpec, scene_folder
from wcbench.scenes.synth.writer import ensure_synth_1, ensure_synth_3, ensure_synth_scenes, write_synth_scene

__all__ = [
    "MATERIALS",
    "SCENES",
    "TRUTH_WEATHERS",
    "VERSION",
    "SynthSpec",
    "build_content",
    "ensure_synth_1",
    "ensure_synth_3",
    "ensure_synth_scenes",
    "gaussian_normals",
    "scene_folder",
    "write_synth_scene",
]
