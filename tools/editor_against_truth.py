"""The physical editor against a synthetic street's weather truth, quickly (issue 36; docs/findings.md).

``bench streets`` scores the editor on ``synth_hard_1`` over every frame and ``bench validity`` on
``synth_1`` / ``synth_3`` among every method; to see what a change to the editor does, this edits
every ``--every``-th frame of each scene in each weather and prints the mean PSNR (dB, display RGB,
whole frame) of the editor and of the raw clear frame against the truth, and the editor's inside the
clear frame's cast shadows where the scene ships ``truth/masks/shadow`` (``synth_hard_*``), also split
by the editor's own surfaces there: facing up (the ground's shadow map) and not (the sun's). The
weathers are the scene's requested ones (``weathers=auto``: rate, visibility, wind, never the
truth's random draw), as every method gets them. Run it at two commits to compare them.

Usage::

    python tools/editor_against_truth.py --scenes synth_1 synth_hard_1 [--weathers rain snow fog] [--every 3]
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import cv2
import numpy as np

from wcbench.methods.physical_editor import raw_frame
from wcbench.methods.weather_spec import resolve_physics
from wcbench.reference_model.appearance.editor import _FACING_UP, WeatherEditor
from wcbench.reference_model.weather.renderer import scale_camera
from wcbench.scenes.sets import get_scene_set


def psnr(a: np.ndarray, b: np.ndarray, mask: np.ndarray) -> float | None:
    """PSNR (dB, peak 1) of display-RGB images [H, W, 3] in [0, 1] over ``mask`` [H, W] bool;
    ``None`` on an empty mask."""
    if not mask.any():
        return None
    mse = float(np.mean((a[mask].astype(np.float64) - b[mask]) ** 2))
    return math.inf if mse == 0 else -10.0 * math.log10(mse)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenes", nargs="+", default=["synth_1", "synth_hard_1"],
                        help="built-in synthetic scene sets (their first scene each)")
    parser.add_argument("--weathers", nargs="+", default=["rain", "snow", "fog"], choices=["rain", "snow", "fog"])
    parser.add_argument("--every", type=int, default=3, help="edit every N-th frame (default 3)")
    args = parser.parse_args()
    if args.every < 1:
        parser.error(f"--every: a positive frame step was expected, got {args.every}")
    for name in args.scenes:
        scene = get_scene_set(name).scenes[0].load()
        if not scene.references:
            raise SystemExit(f"{name}: a scene with weather truth (a synthetic street) was expected")
        editor = WeatherEditor(scene)
        physics = resolve_physics(scene, "auto")
        size = scene.image_size
        scores: dict[str, list[float]] = {}
        for k in range(0, len(scene), args.every):
            raw = raw_frame(scene, k, size)
            camera = scale_camera(scene.frames[k].camera, *size)
            shadow_path = Path(scene.root) / "truth" / "masks" / "shadow" / f"{k:03d}_0.png"
            # only scenes with a sun ship the mask (reading an absent file makes OpenCV warn)
            shadow = cv2.imread(str(shadow_path), cv2.IMREAD_GRAYSCALE) if shadow_path.exists() else None
            for w in args.weathers:
                truth = cv2.cvtColor(cv2.imread(str(scene.references[w][k])), cv2.COLOR_BGR2RGB)
                truth = truth.astype(np.float32) / 255
                edited, _ = editor.edit(raw, k, camera, physics[w])
                everywhere = np.ones(raw.shape[:2], bool)
                rows: list[tuple[str, float | None]] = [(f"editor {w}", psnr(edited, truth, everywhere)),
                                                        (f"raw {w}", psnr(raw, truth, everywhere))]
                if shadow is not None:
                    # the editor's split: a surface facing up is tested against the ground's shadows
                    facing_up = editor.maps(k, camera, raw, fields=()).normal @ editor.surfaces.up > _FACING_UP
                    in_shadow = shadow > 127
                    rows += [(f"editor {w} in shadow", psnr(edited, truth, in_shadow)),
                             (f"editor {w} in shadow, facing up", psnr(edited, truth, in_shadow & facing_up)),
                             (f"editor {w} in shadow, not facing up", psnr(edited, truth, in_shadow & ~facing_up))]
                for key, value in rows:
                    if value is not None:
                        scores.setdefault(key, []).append(value)
        frames = len(range(0, len(scene), args.every))
        print(f"{name} ({frames} frames, every {args.every}):")
        for key, values in scores.items():
            print(f"  {key:40s} {np.mean(values):6.2f} dB")


if __name__ == "__main__":
    main()
