"""Write a scene's sky masks, as this machine's sky segmentation finds them, into ``sky_masks/``.

The lent workstation's OpenCV has no ``cv2.ml`` (the sky segmentation's random forest and EM), so
tools/prepare_workstation_wheels.sh ships the masks computed here with the scene it carries
(docs/workstation.md); the loader reads ``sky_masks/{t:03d}_{camera}.png`` (255 = sky) in place of
the segmentation.

Usage: ``python tools/export_sky_masks.py SCENE_FOLDER``
"""

from __future__ import annotations

import sys
from pathlib import Path

import cv2
import numpy as np

from wcbench.reference_model.scene_analysis.analysis import analyse_scene
from wcbench.scenes.loaders import load_scene


def main(folder: str) -> int:
    """Analyse the scene in ``folder`` and write one mask per frame; return the exit status."""
    root = Path(folder)
    scene = load_scene(root)
    analysis = analyse_scene(scene, log=None)
    out = root / "sky_masks"
    out.mkdir(exist_ok=True)
    for frame, mask in zip(scene.frames, analysis.sky.masks, strict=True):
        name = Path(frame.image_path).stem + ".png"  # {t:03d}_{camera}, as the image
        cv2.imwrite(str(out / name), np.where(mask, 255, 0).astype(np.uint8))
    print(f"{len(scene.frames)} sky masks in {out} ({analysis.sky.facts.get('source', 'segmented')})")
    return 0


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit(f"usage: {sys.argv[0]} SCENE_FOLDER")
    sys.exit(main(sys.argv[1]))
