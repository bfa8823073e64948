"""An object set down at a pose, from this trained scene or carried in from another (``insert ... at=``).

A WeatherCity model's colours are its decoders' reading of a feature learned per scene, so an
object's features mean nothing to another scene's decoders (docs/design.md §7, "Object editing").
A carried object keeps its geometry and opacities (in its box frame) and gets new features in the
target's feature space, chosen so that the target's clear decoder gives the object's own clear
colours:

1. **Exemplars.** Each of its Gaussians takes the mean feature of the 16 target Gaussians, among
   the target's objects of the same class (every node of the target when those have fewer than
   :data:`MIN_POOL` Gaussians), whose clear colour and height in its box are nearest (a k-d tree
   over RGB and the height share weighted by :data:`HEIGHT_WEIGHT`): a roof's grey takes a roof's
   feature, a door's grey a door's. One exemplar alone mottles the other weathers: neighbouring
   Gaussians of one colour take the features of different target cars, whose fog and snow differ
   (docs/findings.md, "An object carried in from another scene").
2. **Refinement.** Adam on those features alone (the decoders frozen): the squared error of the
   target's clear decoder against the object's clear colours, plus a pull toward each exemplar's
   feature, since off the target's own features the decoders' reading of the other weathers is
   not constrained by anything.

Every other weather's colour is then the target's decoder reading that feature: the wet or snowy
look that the target's model learned for surfaces of that colour and height, as an
image analogy carries a learned filter to a new image (Hertzmann et al. 2001, "Image Analogies",
SIGGRAPH). An object of the same scene keeps its features (the same decoders read them).

The pose stands the box on the scene's ground (:func:`ground_point`, :func:`pose_on_ground`): its
length along the world x axis projected on the ground turned by the yaw about the up axis, its
bottom face on the ground below the given world x, y (x, z in a scene whose up is y:
:func:`ground_axes`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np
import torch
from scipy.spatial import cKDTree

from wcbench.core.classes import canonical_class
from wcbench.reference_model.editing.edits import Edit
from wcbench.reference_model.model.gaussians import GaussianParams
from wcbench.reference_model.model.objects import RigidObject
from wcbench.reference_model.model.scene_model import WeatherCityModel
from wcbench.reference_model.scene_graph.completion import ground_height_below

__all__ = ["HEIGHT_WEIGHT", "MIN_POOL", "box_heights", "carried_features", "ground_axes", "ground_point",
           "placed_objects", "pose_on_ground"]

#: Fewest Gaussians of the object's class in the target for the exemplars to come from them alone.
MIN_POOL = 64
#: Weight of the height share in its box (0 at the bottom, 1 at the top) beside RGB in [0, 1] when
#: exemplars are matched: 0.1 of the box's height counts as 0.05 of a colour channel.
HEIGHT_WEIGHT = 0.5
#: Exemplars come from Gaussians at least this opaque (faint ones carry little of any colour).
_MIN_OPACITY = 0.1


def ground_axes(up: np.ndarray) -> tuple[int, int, int]:
    """(first, second, vertical): the world axes that name a place on the ground (the two least
    aligned with ``up``, in order: x and y in a z-up scene, x and z in a y-down one) and the one
    most aligned with it."""
    vertical = int(np.argmax(np.abs(np.asarray(up, np.float64))))
    first, second = (a for a in range(3) if a != vertical)
    return first, second, vertical


def pose_on_ground(at: Sequence[float], *, up: np.ndarray, box_size: np.ndarray,
                   ground: Callable[[float, float], np.ndarray]) -> np.ndarray:
    """[4, 4] object-to-world pose of a box standing on the ground.

    Parameters
    ----------
    at : (a, b, yaw)
        The box's centre seen from above, in world metres along the two world axes that lie nearest
        the ground (:func:`ground_axes`: x, y in a z-up scene), and its yaw (degrees, about ``up``,
        counter-clockwise seen from above; 0 puts the box's length along the first of those axes
        projected on the ground).
    up : ndarray [3]
        The scene's up vector.
    box_size : ndarray [3]
        Length, width, height (m); the box's bottom face rests on the ground.
    ground : callable
        ``(a, b) -> [3]`` the ground's world point below a, b (:func:`ground_point`).
    """
    u = np.asarray(up, np.float64)
    u = u / np.linalg.norm(u)
    first, _, _ = ground_axes(u)
    a, b, yaw = (float(v) for v in at)
    axis = np.zeros(3)
    axis[first] = 1.0
    h0 = axis - u[first] * u
    h0 /= np.linalg.norm(h0)
    angle = math.radians(yaw)
    heading = math.cos(angle) * h0 + math.sin(angle) * np.cross(u, h0)
    left = np.cross(u, heading)
    pose = np.eye(4)
    pose[:3, :3] = np.stack([heading, left, u], 1)
    pose[:3, 3] = np.asarray(ground(a, b), np.float64) + u * float(np.asarray(box_size)[2]) / 2.0
    return pose


def ground_point(points: np.ndarray, a: float, b: float, *, up: np.ndarray, reference: np.ndarray,
                 radius_m: float = 4.0) -> np.ndarray:
    """[3] the ground's world point below the place (a, b) (world metres along :func:`ground_axes`'
    two axes): at the height (along ``up``) of the lidar's lowest returns within ``radius_m``
    sideways (:func:`ground_height_below` about the point at the height of ``reference``, a camera
    centre), or 1.6 m below ``reference``'s height without any.

    Parameters
    ----------
    points : ndarray [N, 3]
        The scene's lidar points (world, m).
    a, b : float
        The place (m).
    up : ndarray [3]
    reference : ndarray [3]
        A camera centre near the place: the height the search starts from.
    """
    u = np.asarray(up, np.float64)
    u = u / np.linalg.norm(u)
    first, second, vertical = ground_axes(u)
    level = float(np.asarray(reference, np.float64) @ u)
    center = np.zeros(3)
    center[first], center[second] = a, b
    center[vertical] = (level - a * u[first] - b * u[second]) / u[vertical]
    height = ground_height_below(points, center, u, radius_m=radius_m)
    return center - u * (level - height)


def box_heights(obj: RigidObject) -> torch.Tensor:
    """[N] each Gaussian's height share in its box: 0 at the bottom face, 1 at the top."""
    h = max(float(obj.box_size[2]), 1e-6)
    return (obj.gaussians.means.detach()[:, 2] / h + 0.5).clamp(0.0, 1.0)


def _exemplar_pool(target: WeatherCityModel, class_name: str) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None,
                                                                          str]:
    """(features [M, F], clear colours [M, 3], height shares [M] or None, what they are) of the target
    Gaussians exemplars come from."""
    same = [o for o in target.objects().values() if canonical_class(o.class_name) == canonical_class(class_name)]
    with torch.no_grad():
        parts = [(o.gaussians.features, box_heights(o), o.gaussians.opacities()) for o in same]
        n = sum(int((op >= _MIN_OPACITY).sum()) for _, _, op in parts)
        if n >= MIN_POOL:
            feats = torch.cat([f[op >= _MIN_OPACITY] for f, _, op in parts])
            heights: torch.Tensor | None = torch.cat([h[op >= _MIN_OPACITY] for _, h, op in parts])
            what = f"{n} Gaussians of the target's {len(same)} {canonical_class(class_name)} object(s)"
        else:
            nodes = list(target.nodes().values())
            feats = torch.cat([p.features[p.opacities() >= _MIN_OPACITY] for p in nodes])
            heights = None
            what = (f"{len(feats)} Gaussians of every node of the target (it has {n} of class "
                    f"{canonical_class(class_name)}, fewer than {MIN_POOL})")
        if len(feats) == 0:
            raise ValueError("the target model has no Gaussian opaque enough to take features from")
        colors = target.decoders(feats, ["clear"])
    return feats.detach(), colors.detach(), heights, what


def carried_features(colors: torch.Tensor, heights: torch.Tensor, target: WeatherCityModel, *, class_name: str,
                     steps: int = 200, lr: float = 0.1, pull: float = 1e-4,
                     neighbours: int = 16) -> tuple[torch.Tensor, dict[str, Any]]:
    """Features [N, F] in ``target``'s feature space whose clear colours are ``colors`` (see the module
    docstring), and what the fit did.

    Parameters
    ----------
    colors : Tensor [N, 3]
        The object's clear colours, in [0, 1] (its own model's clear decoder).
    heights : Tensor [N]
        Each Gaussian's height share in its box (0 bottom, 1 top).
    target : WeatherCityModel
        The model the object is carried into; its decoders are not changed.
    class_name : str
        The object's class: exemplars come from the target's objects of that class when it has
        enough of them.
    steps, lr : int, float
        Adam steps and learning rate of the refinement (0 steps: the exemplars' features).
    pull : float
        Weight of the mean squared distance to the exemplars' features beside the mean squared
        colour error.
    neighbours : int
        Exemplars per Gaussian, whose features are averaged.

    Returns
    -------
    features : Tensor [N, F]
    facts : dict
        ``exemplars`` (where they came from), ``clear_error_exemplars`` and ``clear_error`` (mean
        absolute clear-colour error before and after the refinement, in [0, 1]).
    """
    if steps < 0 or lr <= 0 or pull < 0 or neighbours < 1:
        raise ValueError(f"steps >= 0, lr > 0, pull >= 0 and neighbours >= 1 were expected, got {steps}, {lr}, "
                         f"{pull}, {neighbours}")
    colors = colors.detach().to(torch.float32)
    pool_f, pool_c, pool_h, what = _exemplar_pool(target, class_name)
    if pool_h is not None:
        keys = torch.cat([pool_c, HEIGHT_WEIGHT * pool_h[:, None]], 1).numpy()
        query = torch.cat([colors, HEIGHT_WEIGHT * heights.detach().to(torch.float32)[:, None]], 1).numpy()
    else:
        keys, query = pool_c.numpy(), colors.numpy()
    k = min(neighbours, len(keys))
    _, nearest = cKDTree(keys.astype(np.float64)).query(query.astype(np.float64), k=k)
    nearest = np.asarray(nearest, np.int64).reshape(len(query), k)
    start = pool_f[torch.from_numpy(nearest)].mean(1)
    decoders = target.decoders
    trainable = [p.requires_grad for p in decoders.parameters()]
    for p in decoders.parameters():
        p.requires_grad_(False)
    try:
        with torch.no_grad():
            before = float((decoders(start, ["clear"]) - colors).abs().mean())
        feats = start.clone().requires_grad_(True)
        opt = torch.optim.Adam([feats], lr=lr)
        with torch.enable_grad():
            for _ in range(steps):
                opt.zero_grad()
                loss = (decoders(feats, ["clear"]) - colors).square().mean() + pull * (feats - start).square().mean()
                loss.backward()
                opt.step()
        with torch.no_grad():
            after = float((decoders(feats, ["clear"]) - colors).abs().mean())
    finally:
        for p, flag in zip(decoders.parameters(), trainable):
            p.requires_grad_(flag)
    return feats.detach(), {"exemplars": what, "clear_error_exemplars": round(before, 4),
                            "clear_error": round(after, 4), "steps": steps}


def _standing_copy(obj: RigidObject, features: torch.Tensor, *, track_id: str, pose: np.ndarray,
                   n_frames: int) -> RigidObject:
    """A rigid object of ``obj``'s Gaussians (a non-rigid one's rest shape) with ``features``, at
    ``pose`` in every frame."""
    g = obj.gaussians
    params = GaussianParams(means=g.means.detach().clone(), log_scales=g.log_scales.detach().clone(),
                            quats=g.quats.detach().clone(), opacity_logits=g.opacity_logits.detach().clone(),
                            features=features.detach().clone())
    return RigidObject(params, track_id=track_id, class_name=obj.class_name, frames=np.arange(n_frames),
                       object_to_world=np.repeat(np.asarray(pose, np.float64)[None], n_frames, 0),
                       box_size=obj.box_size, n_frames=n_frames)


def placed_objects(edits: Sequence[Edit], target: WeatherCityModel, *, n_frames: int, up: np.ndarray,
                   ground: Callable[[float, float], np.ndarray],
                   sources: Mapping[str, WeatherCityModel] | None = None,
                   steps: int = 200) -> tuple[list[RigidObject], dict[int, str], list[dict[str, Any]]]:
    """The objects that ``edits``' ``insert ... at=`` set down in ``target``'s scene.

    Parameters
    ----------
    edits : sequence of Edit
        Edits without ``at=`` are passed over.
    target : WeatherCityModel
        The scene's trained model.
    n_frames : int
        Frames of the scene (the objects stand in every one).
    up : ndarray [3]
        The scene's up vector.
    ground : callable
        ``(x, y) -> [3]`` the ground's world point below world x, y (:func:`ground_point`).
    sources : mapping of str to WeatherCityModel, optional
        The trained model of every scene an edit's ``scene=`` names.
    steps : int
        Refinement steps of :func:`carried_features`.

    Returns
    -------
    objects : list of RigidObject
        To add to the model (:meth:`WeatherCityModel.with_objects`).
    keys : dict of int to str
        Edit index -> node key of its object (for :func:`~.edits.placement_for`).
    facts : list of dict
        Per object: the edit, its node, its pose and the feature fit (:func:`carried_features`).

    Raises
    ------
    ValueError
        If a scene= has no model in ``sources``, or the selected id is not an object node of its scene.
    """
    objects: list[RigidObject] = []
    keys: dict[int, str] = {}
    facts: list[dict[str, Any]] = []
    for i, edit in enumerate(edits):
        if edit.at is None:
            continue
        source = target
        if edit.scene is not None:
            if sources is None or edit.scene not in sources:
                raise ValueError(f"edit {edit.to_json()}: no trained model of scene {edit.scene!r} was given")
            source = sources[edit.scene]
        found = [o for o in source.objects().values() if o.track_id == edit.ids[0]]
        if not found:
            where = f"scene {edit.scene!r}" if edit.scene is not None else "this scene"
            nodes = sorted(o.track_id for o in source.objects().values())
            raise ValueError(f"edit {edit.to_json()}: track {edit.ids[0]!r} is not an object node of {where}'s model "
                             f"(nodes: {', '.join(nodes) or 'none'}; a parked car is one unless "
                             "settings.static_nodes=false)")
        obj = found[0]
        fit: dict[str, Any] = {"carried": False}
        features = obj.gaussians.features.detach()
        if source is not target:
            with torch.no_grad():
                colors = source.decoders(features, ["clear"])
            features, fit = carried_features(colors, box_heights(obj), target, class_name=obj.class_name, steps=steps)
            fit = {"carried": True, **fit}
        track_id = f"{edit.scene}/{obj.track_id}#{i}" if edit.scene is not None else f"{obj.track_id}#{i}"
        pose = pose_on_ground(edit.at, up=up, box_size=obj.box_size, ground=ground)
        placed = _standing_copy(obj, features, track_id=track_id, pose=pose, n_frames=n_frames)
        objects.append(placed)
        keys[i] = f"rigid:{track_id}"
        facts.append({"edit": edit.to_json(), "node": keys[i], "class": obj.class_name,
                      "gaussians": len(obj.gaussians), "object_to_world": np.round(pose, 4).tolist(), **fit})
    return objects, keys, facts
