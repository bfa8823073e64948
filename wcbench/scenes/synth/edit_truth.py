"""The editing truth of a synthetic scene: the same frames, clear and under every truth weather,
with a tracked object removed or moved, and per frame a mask of the edited region (docs/design.md §3,
"Editing truth").

Which object is edited follows one rule, so that it is the same for every scene of every set: of
the tracked vehicles that move (the scene graph's nodes), the one whose box centre is in front of
the camera and inside the image in the most frames; ties go to the smaller mean distance from the
camera, then to the smaller id. It is removed (``remove id=N``) and, separately, moved by
:data:`TRANSLATE_BY_M` on the ground (``translate id=N by=10,0,0``). ``N`` is the object's
drivestudio compact instance id, the key of ``instances/instances_info.json`` and the id
``--edit`` selects; ``by`` is in the loaded scene's world frame, which the loaders only translate
from the street's frame (docs/design.md §2), so the offset is the same vector in both.

Everything but the object is rendered exactly as in the plain truth (same Gaussians, shading,
particles and fog), so an edited frame differs from the plain one only where the object was or now
is seen, and through its shadow on profiles with a sun. The mask is the union of the object's
silhouette before and after the edit: pixels where its Gaussians' composited weight is at least
:data:`SILHOUETTE_WEIGHT`, plus (with a sun) pixels whose composited sun visibility changes by at
least as much (its cast shadow, penumbra included; the truth weathers are overcast, shadowless),
plus (with traced mirrors) pixels whose wet ground mirrors the object under rain, before or after
the edit, by as much: its reflection.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from wcbench.core.image_io import to_uint8, write_png
from wcbench.core.storage import dumps_json
from wcbench.scenes.synth.content import Content, Mover
from wcbench.scenes.synth.layout import HEIGHT, TRUTH_WEATHERS, WIDTH
from wcbench.scenes.synth.truth import TruthRenderer

__all__ = ["EDITS_FILE", "EDIT_TRUTH_VERSION", "SILHOUETTE_WEIGHT", "TRANSLATE_BY_M", "EditPlan", "plan_edits",
           "write_edit_truth"]

#: Bump when the edit truth's content or layout changes: a cached scene whose ``edits.json`` has
#: another version gets its edit truth written again (the rest of the scene is left as it is).
EDIT_TRUTH_VERSION = 1
#: ``truth/edits/edits.json``: what was edited, how (as ``--edit`` writes it) and where its frames are.
EDITS_FILE = "edits.json"
#: The move of ``translate`` (m, world frame, on the ground): 10 m along the street's start
#: direction, twice a car's length, so the vacated and the new place are apart.
TRANSLATE_BY_M = (10.0, 0.0, 0.0)
#: A pixel is in an object's silhouette when the object's composited weight there is at least
#: this: half an 8-bit level, so that outside the mask removing the object changes no pixel by
#: more than about one level.
SILHOUETTE_WEIGHT = 0.5 / 255.0


@dataclasses.dataclass(frozen=True)
class EditPlan:
    """One edit of the truth: its folder name, the ``--edit`` JSON form and the object.

    Attributes
    ----------
    name : str
        Folder under ``truth/edits/`` (``remove_<id>``, ``translate_<id>``).
    op : {"remove", "translate"}
    track_id : str
        drivestudio compact instance id.
    mover : int
        Index of the object in ``Content.movers``.
    by : tuple of 3 float or None
        World translation (m) of ``translate``.
    """

    name: str
    op: str
    track_id: str
    mover: int
    by: tuple[float, float, float] | None = None

    def edit_json(self) -> dict[str, Any]:
        """The edit as ``--edit``'s JSON form (:func:`wcbench.reference_model.editing.edits.parse_edits`)."""
        out: dict[str, Any] = {"op": self.op, "ids": [self.track_id]}
        if self.by is not None:
            out["by"] = list(self.by)
        return out

    def edit_text(self) -> str:
        """The edit as ``--edit``'s text form."""
        by = "" if self.by is None else " by=" + ",".join(f"{v:g}" for v in self.by)
        return f"{self.op} id={self.track_id}{by}"


def _in_view(content: Content, cameras: list[Any], shift: np.ndarray, m: Mover) -> tuple[int, float]:
    """Frames whose camera sees ``m``'s box centre in front and inside the image, and the mean
    distance (m) from the camera to it."""
    seen, dist = 0, []
    for k, cam in enumerate(cameras):
        c = m.poses[k][:3, 3] - shift
        uv, z = cam.project(c[None])
        seen += bool(z[0] > 1.0 and 0 <= uv[0, 0] < WIDTH and 0 <= uv[0, 1] < HEIGHT)
        dist.append(float(np.linalg.norm(c - cam.center)))
    return seen, float(np.mean(dist))


def plan_edits(content: Content, cameras: list[Any], shift: np.ndarray) -> list[EditPlan]:
    """The edits of the scene's truth by the module's rule: remove, then translate, the moving
    tracked vehicle in view in the most frames (none when the scene has no such vehicle).

    Parameters
    ----------
    content : Content
    cameras : list of Camera
        Every frame's camera in the loaded world (first camera at the origin).
    shift : ndarray [3]
        Street coordinates of the loaded world's origin.
    """
    tracked = [i for i, m in enumerate(content.movers) if m.tracked]
    compact = {i: str(n) for n, i in enumerate(tracked)}  # writer.py numbers the tracked movers so
    candidates = []
    for i in tracked:
        m = content.movers[i]
        if m.moving and m.class_name == "Vehicle":
            seen, dist = _in_view(content, cameras, shift, m)
            candidates.append((-seen, dist, int(compact[i]), i))
    if not candidates:
        return []
    _, _, _, i = min(candidates)
    return [EditPlan(f"remove_{compact[i]}", "remove", compact[i], i),
            EditPlan(f"translate_{compact[i]}", "translate", compact[i], i, TRANSLATE_BY_M)]


def edited_content(content: Content, plan: EditPlan) -> Content:
    """``content`` with the edit applied: the object dropped, or its poses moved by ``plan.by``."""
    movers = list(content.movers)
    if plan.op == "remove":
        del movers[plan.mover]
    elif plan.op == "translate":
        assert plan.by is not None
        m = movers[plan.mover]
        poses = m.poses.copy()
        poses[:, :3, 3] += np.asarray(plan.by, np.float64)
        movers[plan.mover] = dataclasses.replace(m, poses=poses)
    else:
        raise ValueError(f"edit truth: unknown operation {plan.op!r}; expected 'remove' or 'translate'")
    return dataclasses.replace(content, movers=movers)


def _object_range(content: Content, k: int, mover: int) -> tuple[int, int]:
    """Where mover ``mover``'s Gaussians are in :func:`~.content.cloud_at`'s frame ``k``."""
    start = len(content.static)
    for i, m in enumerate(content.movers):
        if not m.moving:
            continue
        n = len(m.parts(k)[0])
        if i == mover:
            return start, start + n
        start += n
    raise ValueError(f"edit truth: object {mover} is not a moving object of frame {k}")


def _write_mask(path: Path, mask: np.ndarray) -> None:
    """A bool mask [H, W] as an 8-bit PNG, 255 where set (OpenCV's encoder is deterministic)."""
    ok, buf = cv2.imencode(".png", np.where(mask, 255, 0).astype(np.uint8))
    if not ok:
        raise OSError(f"{path}: PNG encoding failed")
    path.write_bytes(buf.tobytes())


def write_edit_truth(folder: Path, content: Content, cameras: list[Any], times: np.ndarray, shift: np.ndarray,
                     plain: TruthRenderer, *, n_frames: int) -> dict[str, Any]:
    """Render and write the editing truth of a scene into ``folder`` (``truth/edits/``).

    Writes ``<name>/{clear,rain,snow,fog}/{t:03d}_0.png``, ``<name>/mask/{t:03d}_0.png`` (255 in
    the edited region) for each edit of :func:`plan_edits`, and last :data:`EDITS_FILE`.

    Parameters
    ----------
    folder : Path
        Created if missing.
    content, cameras, times, shift
        As :class:`~.truth.TruthRenderer` takes them.
    plain : TruthRenderer
        The scene's plain truth renderer (it draws the silhouettes and sun visibility before the edit).
    n_frames : int
        Frames to write (the first ones).

    Returns
    -------
    dict
        The contents of :data:`EDITS_FILE`.
    """
    folder.mkdir(parents=True, exist_ok=True)
    plans = plan_edits(content, cameras, shift)
    records = []
    for plan in plans:
        edited = edited_content(content, plan)
        renderer = TruthRenderer(edited, cameras, times, shift)
        for sub in ("clear", *TRUTH_WEATHERS, "mask"):
            (folder / plan.name / sub).mkdir(parents=True, exist_ok=True)
        pixels = []
        for k in range(n_frames):
            frame = renderer.frame(k)
            for w, f in frame.frames.items():
                write_png(folder / plan.name / w / f"{k:03d}_0.png", to_uint8(np.asarray(f.image, np.float64)))
            region = plain.silhouette(k, content, _object_range(content, k, plan.mover), weight=SILHOUETTE_WEIGHT)
            if plan.op == "translate":
                region |= renderer.silhouette(k, edited, _object_range(edited, k, plan.mover),
                                              weight=SILHOUETTE_WEIGHT)
            if content.spec.profile.sun is not None:  # the object's cast shadow (penumbra included) is edited too
                region |= np.abs(plain.sun_visibility(k) - renderer.sun_visibility(k)) >= SILHOUETTE_WEIGHT
            if content.spec.profile.traced_mirrors:  # and its reflection in the wet ground, before and after
                region |= plain.mirrored_object(k, plan.mover) >= SILHOUETTE_WEIGHT
                if plan.op == "translate":
                    region |= renderer.mirrored_object(k, plan.mover) >= SILHOUETTE_WEIGHT
            _write_mask(folder / plan.name / "mask" / f"{k:03d}_0.png", region)
            pixels.append(int(region.sum()))
        m = content.movers[plan.mover]
        records.append({
            "name": plan.name, "edit": plan.edit_text(), "op": plan.op, "ids": [plan.track_id],
            "by": None if plan.by is None else list(plan.by), "source_id": f"{content.spec.folder}_{m.id}",
            "class_name": m.class_name, "mask_pixels": pixels,
        })
    record = {
        "version": EDIT_TRUTH_VERSION,
        "rule": "the moving tracked vehicle whose box centre is in front of the camera and inside the image in "
                "the most frames (ties: smaller mean distance to the camera, then smaller id); removed, and "
                "separately translated",
        "ids": "drivestudio compact instance ids: the keys of instances/instances_info.json, as --edit names them",
        "frame": "by= in metres in the loaded scene's world frame (first camera at the origin, z up), as --edit's",
        "layout": "<name>/{clear,rain,snow,fog}/{t:03d}_0.png: the edited truth; <name>/mask/{t:03d}_0.png: 255 in "
                  "the edited region (union of the object's silhouette before and after: composited weight "
                  f">= {SILHOUETTE_WEIGHT:.6f}; with a sun, also where the composited sun visibility changes "
                  "by as much: the cast shadow"
                  + ("; with traced mirrors, also where the wet ground's reflected rays meet the object before "
                     "or after by as much: its reflection)" if content.spec.profile.traced_mirrors else ")"),
        "frames": n_frames,
        "edits": records,
    }
    (folder / EDITS_FILE).write_text(dumps_json(record), encoding="utf-8")
    return record


def read_edit_record(folder: Path) -> dict[str, Any] | None:
    """``folder/edits.json`` when it is of :data:`EDIT_TRUTH_VERSION`, else ``None``."""
    try:
        rec = json.loads((folder / EDITS_FILE).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return rec if isinstance(rec, dict) and rec.get("version") == EDIT_TRUTH_VERSION else None
