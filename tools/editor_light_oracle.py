"""Which part of the physical editor's clear-frame light costs it most on a street with cast shadows:
the editor against the harder truth, with parts of its estimate swapped for the truth's (issue 36;
docs/findings.md, "What the editor's light costs on the harder street").

The editor divides each raw pixel by the clear sky's and the sun's irradiance on it
(``sunlit_irradiance``: the sun's direction, its visibility, the surface normal, the sun's direct
light over the sky's) and relights the albedo it gets by the overcast sky. On ``synth_hard_*`` the
truth knows every one of those inputs. Each ``--swap`` set gives the editor the truth's value of
the parts it names, on the pixels the truth's Gaussians cover (accumulated opacity over 0.95), in
the light only (the maps for water, snow and haze stay the editor's):

* ``sun``: the truth's sun direction, in the irradiance and in the editor's own shadow maps (the
  ground's too);
* ``visibility``: the truth's sun visibility (its shadow rays against its own shapes), composited;
* ``normals``: the truth's Gaussians' normals, composited;
* ``direct``: the truth's direct-to-diffuse ratio of the sun;
* ``irradiance``: the truth's whole clear irradiance, relative to a sunlit horizontal surface.

It prints the mean PSNR (dB, display RGB, whole frame) over every ``--every``-th frame of the
editor as it is and with each swap set. Usage::

    python tools/editor_light_oracle.py --swap visibility sun,visibility irradiance [--every 3]
"""

from __future__ import annotations

import argparse
import dataclasses
import math
from collections.abc import Callable
from typing import Any
from unittest import mock

import cv2
import numpy as np
import torch

from wcbench.methods.physical_editor import raw_frame
from wcbench.methods.weather_spec import resolve_physics
from wcbench.reference_model.appearance import editor as editor_module
from wcbench.reference_model.appearance.editor import WeatherEditor
from wcbench.reference_model.raster.rasterizer import rasterize
from wcbench.scenes.loaders import OPENCV_TO_WAYMO
from wcbench.scenes.sets import get_scene_set
from wcbench.scenes.synth.content import build_content, cloud_at
from wcbench.scenes.synth.geometry import gaussian_normals
from wcbench.scenes.synth.layout import HARD_SCENES
from wcbench.scenes.synth.light import clear_irradiance
from wcbench.scenes.synth.shadows import ShadowCaster

PARTS = ("sun", "visibility", "normals", "direct", "irradiance")
#: The truth's scenes by set name (the first scene of each harder set).
SCENES = {"synth_hard_1": HARD_SCENES[0]}


def composite(cloud: Any, values: np.ndarray, camera: Any, shift: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(values composited over alpha [H, W, C], accumulated opacity [H, W]) of per-Gaussian
    ``values`` [N, C] of the truth's ``cloud`` (street coordinates; ``shift``: the loaders' origin
    in them) in ``camera``."""
    t = [torch.from_numpy(np.ascontiguousarray(a, np.float32))
         for a in (cloud.means - shift, cloud.quats, cloud.scales, cloud.opacities, values)]
    with torch.no_grad():
        out = rasterize(*t, torch.from_numpy(np.asarray(camera.world_to_camera, np.float32)),
                        torch.from_numpy(np.asarray(camera.K, np.float32)), int(camera.width), int(camera.height),
                        render_depth=False, absgrad=False)
    alpha = out.alpha.numpy()
    return out.color.numpy() / np.maximum(alpha, 1e-6)[..., None], alpha


def parse_swaps(items: list[str]) -> list[frozenset[str]]:
    """``--swap`` arguments (comma-separated part names) as sets; ValueError naming the parts."""
    swaps = []
    for item in items:
        parts = frozenset(p.strip() for p in item.split(",") if p.strip())
        unknown = sorted(parts - set(PARTS))
        if not parts or unknown:
            raise ValueError(f"--swap {item!r}: comma-separated parts of {', '.join(PARTS)} were expected")
        swaps.append(parts)
    return swaps


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scene", default="synth_hard_1", choices=sorted(SCENES))
    parser.add_argument("--swap", nargs="*", default=["sun", "visibility", "sun,visibility", "irradiance"],
                        help=f"sets of parts taken from the truth, each comma-separated ({', '.join(PARTS)})")
    parser.add_argument("--weathers", nargs="+", default=["rain", "snow", "fog"], choices=["rain", "snow", "fog"])
    parser.add_argument("--every", type=int, default=3, help="edit every N-th frame (default 3)")
    args = parser.parse_args()
    if args.every < 1:
        parser.error(f"--every: a positive frame step was expected, got {args.every}")
    try:
        swaps = parse_swaps(args.swap)
    except ValueError as exc:
        parser.error(str(exc))

    scene = get_scene_set(args.scene).scenes[0].load()
    physics = resolve_physics(scene, "auto")
    content = build_content(SCENES[args.scene])
    sun = content.spec.profile.sun
    if sun is None:  # every scene of SCENES has one; a guard for a set added without
        raise SystemExit(f"{args.scene}: a scene whose clear frames have a sun was expected")
    cameras = [f.camera for f in scene.frames]  # the loaders' frame: the truth's cameras, its origin shifted
    shift = (content.ego[0] @ content.camera_to_vehicle @ OPENCV_TO_WAYMO)[:3, 3]
    shadows = ShadowCaster(content)  # the truth's own shadow rays, without its weather renderers
    lit_horizontal = clear_irradiance(sun, np.array([[0.0, 0.0, 1.0]]), np.ones(1))[0]
    truth_d2d = np.asarray(sun.sun_rgb) * sun.direction()[2] / np.asarray(sun.sky_rgb)
    # the street's axes are the loaders' (only the origin moves), so a street direction is a world one
    truth_sun = sun.direction()

    base_editor = WeatherEditor(scene)
    editors: dict[frozenset[str], WeatherEditor] = {frozenset(): base_editor}
    for parts in swaps:
        ed = WeatherEditor(scene)
        if "sun" in parts:
            fitted = ed.analysis.sun
            ed.analysis = dataclasses.replace(ed.analysis, sun=dataclasses.replace(fitted, direction=truth_sun,
                                                                               ground_direction=None))
        editors[parts] = ed
    original = editor_module.sunlit_irradiance
    here: dict[str, np.ndarray] = {}

    def swapped(parts: frozenset[str]) -> Callable[..., np.ndarray]:
        def irradiance(normal: np.ndarray, visibility: np.ndarray, **kw: Any) -> np.ndarray:
            solid = here["alpha"] > 0.95
            if "irradiance" in parts:
                return np.where(solid[..., None], here["irradiance"], original(normal, visibility, **kw)
                                ).astype(np.float32)
            if "visibility" in parts:
                visibility = np.where(solid, here["visibility"], visibility)
            if "normals" in parts:
                normal = np.where(solid[..., None], here["normals"], normal)
            if "direct" in parts:
                kw["direct_to_diffuse"] = truth_d2d
            return original(normal, visibility, **kw)
        return irradiance

    scores: dict[tuple[frozenset[str], str], list[float]] = {}
    for k in range(0, len(scene), args.every):
        raw = raw_frame(scene, k, scene.image_size)
        camera = cameras[k]
        cloud = cloud_at(content, k)
        normals = gaussian_normals(cloud.quats, cloud.scales)
        visibility = shadows.visibility(k, cloud)
        values = np.concatenate([normals, visibility[:, None], clear_irradiance(sun, normals, visibility)], 1)
        mixed, here["alpha"] = composite(cloud, values, camera, shift)
        n = mixed[..., :3]
        here["normals"] = (n / np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-6)).astype(np.float32)
        here["visibility"] = mixed[..., 3].astype(np.float32)
        here["irradiance"] = (mixed[..., 4:] / lit_horizontal).astype(np.float32)
        for w in args.weathers:
            target = cv2.cvtColor(cv2.imread(str(scene.references[w][k])), cv2.COLOR_BGR2RGB).astype(np.float64) / 255
            for parts, ed in editors.items():
                with mock.patch.object(editor_module, "sunlit_irradiance", swapped(parts)):
                    edited, _ = ed.edit(raw, k, camera, physics[w])
                mse = float(np.mean((edited.astype(np.float64) - target) ** 2))
                scores.setdefault((parts, w), []).append(-10.0 * math.log10(max(mse, 1e-12)))
    frames = len(range(0, len(scene), args.every))
    print(f"{args.scene} ({frames} frames, every {args.every}), editor PSNR (dB) by what it takes from the truth:")
    print(f"  {'taken from the truth':34s}" + "".join(f"{w:>8s}" for w in args.weathers))
    for parts in editors:
        label = ",".join(p for p in PARTS if p in parts) or "nothing (the editor)"
        print(f"  {label:34s}" + "".join(f"{np.mean(scores[(parts, w)]):8.2f}" for w in args.weathers))


if __name__ == "__main__":
    main()
