"""Edited frames scored against a scene's editing truth: on the whole frame and on the edited region
(docs/design.md §3, "Editing truth")."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from scene_fixtures import write_prediction_folder

from wcbench.cli import main
from wcbench.scenes.scene import EditTruth, Scene, edits_key

REMOVE_3 = {"op": "remove", "ids": ["3"]}


def _truth(scene: Scene, root: Path) -> EditTruth:
    """An editing truth of ``remove id=3``: the raw frames with a grey box painted in rows 20-39,
    columns 40-79, which is also the mask."""
    refs, masks = [], []
    for f in scene.frames:
        img = cv2.imread(str(f.image_path))
        img[20:40, 40:80] = 90
        refs.append(root / f"{f.index:03d}.png")
        cv2.imwrite(str(refs[-1]), img)
        mask = np.zeros(img.shape[:2], np.uint8)
        mask[20:40, 40:80] = 255
        masks.append(root / f"mask_{f.index:03d}.png")
        cv2.imwrite(str(masks[-1]), mask)
    return EditTruth(name="remove_3", edit=REMOVE_3, references={"clear": refs}, masks=masks)


def _evaluate(demo_scene: Scene, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, edits: list) -> dict:
    root = tmp_path / "truth"
    root.mkdir(exist_ok=True)
    truth = _truth(demo_scene, root)
    original = Scene.edit_truth

    def with_truth(self: Scene, run_edits: list) -> EditTruth | None:
        self.edit_truths = [truth]
        return original(self, run_edits)

    monkeypatch.setattr(Scene, "edit_truth", with_truth)
    preds = write_prediction_folder(demo_scene, tmp_path / "preds", ["clear"])  # the object left in place
    (preds / "info.json").write_text(json.dumps({"parameters": {"edits": edits}}))
    out = tmp_path / "out"
    assert main(["evaluate", "--method", "folder", "--scenes", "demo", "--predictions", str(preds),
                 "--out", str(out), "--metrics", "psnr,ssim", "--no-progress"]) == 0
    return json.loads((out / "results.json").read_text())


def test_an_edit_with_truth_is_scored_on_the_whole_frame_and_the_region(demo_scene, tmp_path, monkeypatch):
    doc = _evaluate(demo_scene, tmp_path, monkeypatch, [{"op": "remove", "ids": ["3"]}])
    res = doc["results"]["demo"]["clear"]
    # the region's PSNR by hand: the raw frames against the painted box, over the box's pixels only
    expected, whole = [], []
    for f in demo_scene.frames:
        raw = cv2.imread(str(f.image_path)).astype(np.float64) / 255
        edited = raw.copy()
        edited[20:40, 40:80] = 90 / 255
        expected.append(10 * np.log10(1 / np.mean((raw[20:40, 40:80] - edited[20:40, 40:80]) ** 2)))
        whole.append(10 * np.log10(1 / np.mean((raw - edited) ** 2)))
    assert res["psnr_edit_region"]["value"] == pytest.approx(np.mean(expected), rel=1e-6)
    assert res["psnr"]["value"] == pytest.approx(np.mean(whole), rel=1e-6)  # against the editing truth
    assert res["psnr"]["value"] > res["psnr_edit_region"]["value"] + 5  # the frame dilutes the error
    assert res["ssim_edit_region"]["value"] < res["ssim"]["value"] < 1.0
    assert "mask's bounding box" in res["ssim_edit_region"]["variant"]


def test_an_edit_without_truth_says_so_for_the_region(demo_scene, tmp_path, monkeypatch):
    doc = _evaluate(demo_scene, tmp_path, monkeypatch, [{"op": "remove", "ids": ["4"]}])
    res = doc["results"]["demo"]["clear"]
    assert "psnr_edit_region" not in res and res["psnr"]["value"] is None  # the raw frames: identical
    reasons = {s["metric"]: s["reason"] for s in doc["skipped"]}
    assert reasons["psnr (edit region)"] == reasons["ssim (edit region)"] == "no editing truth for this edit"


def test_edits_match_in_text_and_json_forms_only_when_equal():
    assert edits_key([{"op": "remove", "id": "3"}]) == edits_key([REMOVE_3])
    move = {"op": "translate", "ids": ["3"], "by": [10, 0, 0]}
    assert edits_key([move]) == edits_key([{"op": "translate", "ids": "3", "by": [10.0, 0.0, 1e-9]}])
    assert edits_key([move]) != edits_key([{**move, "by": [9, 0, 0]}])
    assert edits_key([REMOVE_3]) != edits_key([REMOVE_3, REMOVE_3]) and edits_key([]) is None


@pytest.mark.parametrize(("rows", "cols", "expected"), [
    ((20, 70), (40, 120), ((12, 78), (32, 128))),  # the box grown by 8 px
    ((20, 40), (40, 80), ((0, 64), (28, 92))),  # then to 64 px about its centre, inside the image
    ((0, 2), (0, 2), ((0, 64), (0, 64))),  # small, at a corner: 64 px a side, inside the image
    ((95, 96), (150, 151), ((36, 100), (96, 160))),  # small, at the far corner
])
def test_region_box_grows_small_regions_inside_the_image(rows, cols, expected):
    from wcbench.metrics.base import region_box

    mask = np.zeros((100, 160), bool)
    mask[rows[0]:rows[1], cols[0]:cols[1]] = True
    box = region_box(mask)
    assert box is not None and tuple((s.start, s.stop) for s in box) == expected
    assert region_box(np.zeros((100, 160), bool)) is None
