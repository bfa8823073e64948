"""Procedural driving scenes with ground-truth weather: the ``synth_1``, ``synth_3`` and ``synth_hard_1``
scene sets.

No public dataset shows the same street under true rain, snow and fog, so these scenes are built
from known content (docs/design.md §3): a street of 3D Gaussians (road with lane markings, raised
sidewalks, building facades with windows, trees, parked cars, moving cars and, in some scenes, a
walking pedestrian) seen by a camera driving at 8 m/s. Every frame, clear and each weather, is
rendered by the reference model's :class:`~wcbench.reference_model.weather.renderer.WeatherRenderer`
(docs/design.md §7). A weather first changes the materials (wet asphalt with a sky sheen and
puddles under rain, snow cover on upward-facing Gaussians, dimmer overcast light), then the rain
and snow particles and the fog come from the model's physics.

``synth_hard_1`` (profile :data:`~.layout.HARD`) measures what real cameras do to an editor and
the v1 streets do not: its clear frames have a low sun casting shadows (moving objects' shadows
move with them), its lidar is a 64-beam PandaSet-like sensor under blocks whose upper floors it does
not reach, it ships no sky masks, some moving cars and pedestrians have no box, and dark road
patches, a white facade and mirroring windows cannot be read from the clear pixel. It writes truth
masks (sky, cast shadow, movers) for scoring.

Each scene is written in drivestudio's Waymo layout, exactly as
:func:`wcbench.scenes.loaders.load_waymo_layout` reads it, with the truth beside it
(``truth/{weather}/{t:03d}_0.png`` and ``truth/weather.json``). Scenes are generated on first use
into the cache folder of their profile (``scenes/synth-v1/synth_{k:03d}``,
``scenes/synth-hard-v2/synth_hard_000``), built in a temporary folder and renamed into place;
generation is seeded and byte-for-byte deterministic (PNG images, fixed text formats).

Rendering needs the reference model (torch and numba, the ``[model]`` extra); a scene already in the
cache loads without it.

The package: :mod:`.layout` (constants, truth weathers, v1's materials, the profiles, the scenes of
the sets), :mod:`.geometry` (poses, the street centreline, surface Gaussians), :mod:`.content` (what
a scene holds), :mod:`.raycast` (rays against boxes and spheres), :mod:`.lidar` (the sweeps),
:mod:`.light` (sun, sky and overcast light), :mod:`.shadows` (what the sun reaches),
:mod:`.materials` (surfaces under each weather, from the shared appearance tables), :mod:`.truth`
(shading and rendering every weather, the truth masks), :mod:`.edit_truth` (the same frames with a
tracked car removed or moved, and the edited region's masks: ``truth/edits/``) and :mod:`.writer`
(the dataset layout on disk and the cache).
"""

from __future__ import annotations

from wcbench.scenes.synth.content import build_content
from wcbench.scenes.synth.geometry import gaussian_normals
from wcbench.scenes.synth.layout import (
    HARD,
    HARD_SCENES,
    MATERIALS_V1,
    SCENES,
    TRUTH_WEATHERS,
    V1,
    VERSION,
    Profile,
    SynthSpec,
    scene_folder,
)
from wcbench.scenes.synth.writer import (
    ensure_synth_1,
    ensure_synth_3,
    ensure_synth_hard_1,
    ensure_synth_scenes,
    write_synth_scene,
)

__all__ = [
    "HARD",
    "HARD_SCENES",
    "MATERIALS_V1",
    "SCENES",
    "TRUTH_WEATHERS",
    "V1",
    "VERSION",
    "Profile",
    "SynthSpec",
    "build_content",
    "ensure_synth_1",
    "ensure_synth_3",
    "ensure_synth_hard_1",
    "ensure_synth_scenes",
    "gaussian_normals",
    "scene_folder",
    "write_synth_scene",
]
