"""The WeatherCity scene graph: background, rigid and non-rigid nodes of weather Gaussians, a sky.

:meth:`WeatherCityModel.frame_gaussians` places every node at a frame and concatenates their
Gaussians; :meth:`WeatherCityModel.render` decodes the colors of several weathers at once and
rasterizes them as stacked channels in **one** pass (geometry is shared, so depth and alpha are
the same for every weather), then puts each weather's sky behind the Gaussians:

    I_w = C_w + (1 - A) S_w,      C_w = sum_i c_i^w alpha_i T_i,   A = sum_i alpha_i T_i

with S_w the weather's environment map looked up along each pixel's ray (docs/design.md §7). A
weather given a haze (training on edited frames, :mod:`.haze`) is composed through it instead:
one more channel per hazy weather carries the Gaussians' transmittance.
Node placement can be changed per render (edits: hide, move or copy nodes, :class:`Placement`).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, cast

import numpy as np
import torch
from torch import nn

from wcbench.reference_model.model.decoders import WeatherDecoders
from wcbench.reference_model.model.gaussians import GaussianParams, activate_opacities, activate_scales
from wcbench.reference_model.model.haze import Haze, compose_haze, haze_transmittance, hazy_weathers
from wcbench.reference_model.model.objects import NonRigidObject, RigidObject, place_objects
from wcbench.reference_model.model.sky import SkyModel
from wcbench.reference_model.raster.rasterizer import rasterize

__all__ = ["FrameGaussians", "FrameRows", "Placement", "WeatherCityModel", "WeatherRender"]

#: Key of the background node; objects are ``rigid:<track id>`` and ``nonrigid:<track id>``.
BACKGROUND = "background"


@dataclass
class Placement:
    """How nodes are placed at render time (object editing).

    Attributes
    ----------
    hidden : set of str
        Node keys not rendered.
    offsets : dict of str to ndarray [3]
        World translation (m) added to an object's pose.
    copies : list of (str, ndarray [3])
        Extra instances: (node key, world translation of the copy).
    """

    hidden: set[str] = field(default_factory=set)
    offsets: dict[str, np.ndarray] = field(default_factory=dict)
    copies: list[tuple[str, np.ndarray]] = field(default_factory=list)


@dataclass
class FrameGaussians:
    """All Gaussians of a frame in world coordinates, concatenated node by node.

    ``segments`` lists (node key, start, stop) of each node's rows (a copied node appears twice);
    ``nodes`` maps each key to its parameters (features stay per node; :meth:`colors` decodes
    their concatenation).
    """

    means: torch.Tensor  # [N, 3] m
    quats: torch.Tensor  # [N, 4]
    scales: torch.Tensor  # [N, 3] m
    opacities: torch.Tensor  # [N]
    segments: list[tuple[str, int, int]]
    nodes: dict[str, GaussianParams]

    def __len__(self) -> int:
        return int(self.means.shape[0])

    def colors(self, decode: Callable[[torch.Tensor], torch.Tensor]) -> torch.Tensor:
        """``decode(features [n, F]) -> [n, C]`` of every node, in row order: [N, C].

        The placed nodes' features are decoded in one call on their concatenation (a copied node
        once): one GEMM per layer instead of one per node, whose per-call overhead dominated the
        decoders' time with a few dozen small objects (docs/design.md §8).
        """
        keys = list(dict.fromkeys(key for key, _, _ in self.segments))
        if not keys:  # nothing placed: frame_gaussians keeps an empty node to give the width
            return decode(next(iter(self.nodes.values())).features)
        features: list[torch.Tensor] = [self.nodes[key].features for key in keys]
        decoded = decode(features[0] if len(features) == 1 else torch.cat(features))
        if len(keys) == len(self.segments):  # no copies: rows are already in segment order
            return decoded
        done = dict(zip(keys, torch.split(decoded, [len(f) for f in features])))
        return torch.cat([done[key] for key, _, _ in self.segments])


@dataclass
class WeatherRender:
    """One render of several weathers of a frame.

    Attributes
    ----------
    images : Tensor [H, W, 3 len(weathers)]
        RGB in [0, 1] of each weather, sky included, weather-major channels.
    alpha : Tensor [H, W]
        Accumulated opacity of the Gaussians (the same for every weather).
    depth : Tensor [H, W] or None
        Expected depth of the Gaussians (m).
    raster : Any
        The rasterizer's output (``means2d_abs`` for densification, ``meta`` counters).
    gaussians : FrameGaussians
    weathers : tuple of str
    """

    images: torch.Tensor
    alpha: torch.Tensor
    depth: torch.Tensor | None
    raster: Any
    gaussians: FrameGaussians
    weathers: tuple[str, ...]

    def image(self, weather: str) -> torch.Tensor:
        """[H, W, 3] of one weather."""
        k = self.weathers.index(weather)
        return self.images[..., 3 * k : 3 * k + 3]


class WeatherCityModel(nn.Module):
    """Weather Gaussians on a scene graph (sky, background, rigid and non-rigid nodes).

    Parameters
    ----------
    background : GaussianParams
        Static Gaussians in world coordinates.
    rigid, nonrigid : sequence of RigidObject / NonRigidObject
        Moving objects; empty sequences build no such node (and run none of its code).
    decoders : WeatherDecoders
    sky : SkyModel
    """

    def __init__(self, background: GaussianParams, rigid: Sequence[RigidObject],
                 nonrigid: Sequence[NonRigidObject], decoders: WeatherDecoders, sky: SkyModel):
        super().__init__()
        self.background = background
        self.rigid = nn.ModuleList(rigid)
        self.nonrigid = nn.ModuleList(nonrigid)
        self.decoders = decoders
        self.sky = sky
        #: How :meth:`frame_gaussians` places the objects (:func:`.objects.place_objects`): ``None``,
        #: batched on a CUDA device (a GPU step is bound by its kernel launches) and object by object
        #: elsewhere (as before); ``True`` / ``False`` force one (tools/gpu_step_profile.py).
        self.batched_placement: bool | None = None

    @property
    def weathers(self) -> tuple[str, ...]:
        """Weathers the decoders know."""
        return self.decoders.weathers

    def rigid_objects(self) -> list[RigidObject]:
        """The rigid nodes (typed view of the module list)."""
        return [cast(RigidObject, o) for o in self.rigid]

    def nonrigid_objects(self) -> list[NonRigidObject]:
        """The non-rigid nodes (typed view of the module list)."""
        return [cast(NonRigidObject, o) for o in self.nonrigid]

    def objects(self) -> dict[str, RigidObject]:
        """Every object node by key (``rigid:<id>`` / ``nonrigid:<id>``)."""
        out = {f"rigid:{o.track_id}": o for o in self.rigid_objects()}
        out.update({f"nonrigid:{o.track_id}": o for o in self.nonrigid_objects()})
        return out

    def with_objects(self, extra: Sequence[RigidObject]) -> WeatherCityModel:
        """This model with ``extra`` rigid objects added (objects set down by an edit): a new model
        that shares every node, decoder and sky map with this one (nothing is copied)."""
        keys = set(self.objects())
        clash = sorted(f"rigid:{o.track_id}" for o in extra if f"rigid:{o.track_id}" in keys)
        if clash:
            raise ValueError(f"objects {clash} are nodes of the model already")
        return WeatherCityModel(self.background, [*self.rigid_objects(), *extra], self.nonrigid_objects(),
                                self.decoders, self.sky)

    def with_background(self, background: GaussianParams) -> WeatherCityModel:
        """This model with ``background`` for its background node (an edit's filled background): a new
        model that shares every object, decoder and sky map with this one."""
        if background.feature_dim != self.background.feature_dim:
            raise ValueError(f"the background's features have {background.feature_dim} channels; the "
                             f"decoders read {self.background.feature_dim}")
        return WeatherCityModel(background, self.rigid_objects(), self.nonrigid_objects(), self.decoders, self.sky)

    def nodes(self) -> dict[str, GaussianParams]:
        """The Gaussians of every node by key, the background first."""
        out = {BACKGROUND: self.background}
        out.update({key: obj.gaussians for key, obj in self.objects().items()})
        return out

    def counts(self) -> dict[str, int]:
        """Gaussians per node type: background, rigid, nonrigid, total."""
        rigid = sum(len(o.gaussians) for o in self.rigid_objects())
        nonrigid = sum(len(o.gaussians) for o in self.nonrigid_objects())
        return {"background": len(self.background), "rigid": rigid, "nonrigid": nonrigid,
                "rigid_nodes": len(self.rigid), "nonrigid_nodes": len(self.nonrigid),
                "total": len(self.background) + rigid + nonrigid}

    def frame_gaussians(self, frame: int, placement: Placement | None = None, *,
                        activated: dict[str, tuple[torch.Tensor, torch.Tensor]] | None = None) -> FrameGaussians:
        """Every node's Gaussians placed at ``frame`` (world coordinates), concatenated.

        Parameters
        ----------
        frame : int
            Scene frame; objects not annotated there are absent.
        placement : Placement, optional
            Hidden, moved and copied nodes (object editing).
        activated : dict of str to (Tensor [n, 3], Tensor [n]), optional
            Each node's scales (m) and opacities computed once (:meth:`activated`): rendering a
            trained model needs no exp and sigmoid of every Gaussian per frame.
        """
        place = placement or Placement()
        means_device = self.background.means.device
        objects = self.objects()
        instances: list[tuple[str, np.ndarray | None]] = [
            (key, place.offsets.get(key)) for key in objects if key not in place.hidden
        ]
        instances += [(key, np.asarray(offset)) for key, offset in place.copies]
        placed: list[tuple[str, RigidObject, torch.Tensor | None]] = []
        for key, offset in instances:
            if key not in objects:
                raise KeyError(f"no node {key!r}; nodes: {sorted(objects)}")
            obj = objects[key]
            if obj.at(frame):
                off = None if offset is None else torch.as_tensor(np.asarray(offset, np.float32), device=means_device)
                placed.append((key, obj, off))
        parts: list[tuple[str, GaussianParams]] = []
        means: list[torch.Tensor] = []
        quats: list[torch.Tensor] = []
        if BACKGROUND not in place.hidden:
            parts.append((BACKGROUND, self.background))
            means.append(self.background.means)
            quats.append(self.background.quats)
        if placed:
            batched = self.batched_placement if self.batched_placement is not None else means_device.type == "cuda"
            m, q = place_objects([(obj, off) for _, obj, off in placed], frame, batched=batched)
            parts += [(key, obj.gaussians) for key, obj, _ in placed]
            means.append(m)
            quats.append(q)
        segments, start = [], 0
        for key, params in parts:
            segments.append((key, start, start + len(params)))
            start += len(params)
        nodes = dict(parts)
        if not parts:
            empty = GaussianParams.empty(self.background.feature_dim, self.sky.basis.device)
            parts, means, quats, nodes = [(BACKGROUND, empty)], [empty.means], [empty.quats], {BACKGROUND: empty}
            activated = None
        keys = [key for key, _ in parts]
        if activated is not None and all(key in activated for key in keys):
            scales = torch.cat([activated[key][0] for key in keys])
            opacities = torch.cat([activated[key][1] for key in keys])
        else:  # once on the concatenation: elementwise, node by node's values (sigmoid's to 1 ulp)
            scales = activate_scales(torch.cat([params.log_scales for _, params in parts]))
            opacities = activate_opacities(torch.cat([params.opacity_logits for _, params in parts]))
        return FrameGaussians(means=torch.cat(means), quats=torch.cat(quats), scales=scales, opacities=opacities,
                              segments=segments, nodes=nodes)

    def activated(self) -> dict[str, tuple[torch.Tensor, torch.Tensor]]:
        """Each node's scales [n, 3] (m) and opacities [n], detached (for :meth:`frame_gaussians`)."""
        with torch.no_grad():
            return {key: (p.scales(), p.opacities()) for key, p in self.nodes().items()}

    def render(
        self,
        frame: int,
        world_to_camera: np.ndarray,
        K: np.ndarray,
        width: int,
        height: int,
        weathers: Sequence[str],
        *,
        sky_grid: torch.Tensor,
        depth: bool = True,
        absgrad: bool = False,
        placement: Placement | None = None,
        rasterizer: Callable[..., Any] = rasterize,
        hazes: Mapping[str, Haze] | None = None,
    ) -> WeatherRender:
        """Render ``weathers`` of ``frame`` in one rasterization pass (differentiable).

        Parameters
        ----------
        frame : int
        world_to_camera : ndarray [4, 4]
            OpenCV axes.
        K : ndarray [3, 3]
            Intrinsics in pixels at ``width`` x ``height``.
        weathers : sequence of str
            Decoded and stacked as channels, in this order.
        sky_grid : Tensor [1, H, W, 2]
            :meth:`SkyModel.grid` of the camera's ray directions.
        depth, absgrad : bool
            As :func:`~wcbench.reference_model.raster.rasterizer.rasterize`.
        placement : Placement, optional
        rasterizer : callable
            ``rasterize``-compatible (tests inject the pure-torch twin).
        hazes : mapping of str to Haze, optional
            Weathers rendered through their Beer-Lambert haze (:mod:`.haze`); the others, and a
            haze of beta 0, get their sky behind the Gaussians.
        """
        g = self.frame_gaussians(frame, placement)
        colors = g.colors(lambda f: self.decoders(f, weathers))  # [N, 3 len(weathers)]
        hazy = hazy_weathers(weathers, hazes)
        w2c = np.asarray(world_to_camera, np.float64)
        if hazy:
            center = torch.from_numpy(-w2c[:3, :3].T @ w2c[:3, 3]).to(device=colors.device, dtype=colors.dtype)
            t = haze_transmittance(g.means, center, list(hazy.values()))  # [N, K]
            column = {w: j for j, w in enumerate(hazy)}
            parts = [colors[:, 3 * i:3 * i + 3] * t[:, column[w], None] if w in column else colors[:, 3 * i:3 * i + 3]
                     for i, w in enumerate(weathers)]
            colors = torch.cat([*parts, t], 1)  # [N, 3 len(weathers) + K]
        out = rasterizer(
            g.means, g.quats, g.scales, g.opacities, colors,
            torch.from_numpy(w2c.astype(np.float32)), torch.from_numpy(np.asarray(K, np.float32)),
            int(width), int(height), render_depth=depth, absgrad=absgrad,
        )
        n = 3 * len(weathers)
        sky = self.sky(sky_grid, weathers)
        images = out.color[..., :n] + (1.0 - out.alpha)[..., None] * sky
        if hazy:
            images = torch.cat([
                compose_haze(out.color[..., 3 * i:3 * i + 3], out.color[..., n + column[w]], out.alpha, hazy[w])
                if w in column else images[..., 3 * i:3 * i + 3] for i, w in enumerate(weathers)], -1)
        return WeatherRender(images=images, alpha=out.alpha, depth=out.depth, raster=out, gaussians=g,
                             weathers=tuple(weathers))


class FrameRows:
    """Every placed node's Gaussians in rows fixed for a whole sequence: rendering a trained model.

    :meth:`WeatherCityModel.frame_gaussians` concatenates the nodes present at a frame, so each
    frame builds and copies every Gaussian (125k rows) although only the moving nodes' rows change.
    Here the background and every instance (the placement's objects and copies, in
    :meth:`~WeatherCityModel.frame_gaussians`' order) hold fixed rows of float32 arrays, built
    once; :meth:`place` rewrites only the moving nodes' centres and rotations (the same torch
    products as :meth:`RigidObject.world`, without BLAS, so equal within float32 rounding), and
    gives an instance absent at the frame opacity 0, which the rasterizer culls before sorting. The
    Gaussians a frame rasterizes are then those of ``frame_gaussians`` in the same relative order
    (depth ties break by index), so the image is the same up to that rounding; ``frame_gaussians``
    is the twin the tests compare it with.

    Parameters
    ----------
    model : WeatherCityModel
    colors : dict of str to Tensor [n, C]
        Each node's decoded colours (one weather's decoders, decoded once).
    placement : Placement, optional
    activated : dict of str to (Tensor [n, 3], Tensor [n]), optional
        :meth:`WeatherCityModel.activated` (computed here when omitted).

    Attributes
    ----------
    arrays : dict of str to ndarray
        ``means`` [N, 3] (m), ``quats`` [N, 4], ``scales`` [N, 3] (m), ``opacities`` [N],
        ``colors`` [N, C], float32, written in place by :meth:`place`.
    """

    def __init__(self, model: WeatherCityModel, colors: Mapping[str, torch.Tensor], *,
                 placement: Placement | None = None,
                 activated: dict[str, tuple[torch.Tensor, torch.Tensor]] | None = None):
        place = placement or Placement()
        objects = model.objects()
        nodes = model.nodes()
        if activated is None:
            activated = model.activated()
        instances: list[tuple[str, torch.Tensor | None]] = []
        if BACKGROUND not in place.hidden:
            instances.append((BACKGROUND, None))
        offsets = [(key, place.offsets.get(key)) for key in objects if key not in place.hidden]
        for key, shift in [*offsets, *((key, np.asarray(off)) for key, off in place.copies)]:
            if key not in objects:
                raise KeyError(f"no node {key!r}; nodes: {sorted(objects)}")
            instances.append((key, None if shift is None else torch.as_tensor(np.asarray(shift, np.float32))))
        missing = sorted({key for key, _ in instances} - set(colors))
        if missing:
            raise ValueError(f"colors must hold every placed node; missing {missing}")
        width = int(next(iter(colors.values())).shape[1]) if colors else 3
        n = sum(len(nodes[key]) for key, _ in instances)
        self.arrays: dict[str, np.ndarray] = {
            "means": np.zeros((n, 3), np.float32), "quats": np.zeros((n, 4), np.float32),
            "scales": np.zeros((n, 3), np.float32), "opacities": np.zeros(n, np.float32),
            "colors": np.zeros((n, width), np.float32)}
        #: (object, its offset, first row, end row, opacities when present) of each moving instance
        self._moving: list[tuple[RigidObject, torch.Tensor | None, int, int, np.ndarray]] = []
        self._present: list[bool | None] = []
        start = 0
        with torch.no_grad():
            for key, offset in instances:
                params = nodes[key]
                stop = start + len(params)
                scales, opacities = activated[key] if key in activated else (params.scales(), params.opacities())
                self.arrays["scales"][start:stop] = scales.detach().numpy()
                self.arrays["colors"][start:stop] = colors[key].detach().numpy()
                if key == BACKGROUND:
                    self.arrays["means"][start:stop] = params.means.detach().numpy()
                    self.arrays["quats"][start:stop] = params.quats.detach().numpy()
                    self.arrays["opacities"][start:stop] = opacities.detach().numpy()
                else:
                    self._moving.append((objects[key], offset, start, stop,
                                         np.array(opacities.detach().numpy(), np.float32)))
                    self._present.append(None)
                start = stop

    def __len__(self) -> int:
        return int(self.arrays["means"].shape[0])

    def place(self, frame: int) -> list[slice]:
        """Write the moving instances' rows for ``frame``; returns the row ranges written.

        An instance present at ``frame`` gets its world centres and rotations (and its opacities
        back if it was absent); an absent one keeps its last rows at opacity 0.
        """
        written = []
        with torch.no_grad():
            for k, (obj, offset, start, stop, opacities) in enumerate(self._moving):
                present = obj.at(frame)
                if present:
                    p = obj.position[frame] if offset is None else obj.position[frame] + offset
                    _affine_rows(obj.local_means(frame).detach().numpy(), obj.rotation[frame].numpy(), p.numpy(),
                                 out=self.arrays["means"][start:stop])
                    _affine_rows(obj.gaussians.quats.detach().numpy(), obj.quat_left[frame].numpy(), None,
                                 out=self.arrays["quats"][start:stop])
                if present != self._present[k]:
                    self.arrays["opacities"][start:stop] = opacities if present else 0.0
                    self._present[k] = present
                elif not present:
                    continue
                written.append(slice(start, stop))
        return written


def _affine_rows(x: np.ndarray, m: np.ndarray, b: np.ndarray | None, *, out: np.ndarray) -> None:
    """``out = x m^T + b`` for x [n, k], m [d, k], b [d] (float32), written into out [n, d].

    Column by column in numpy: no BLAS call, whose threads wake for every one of a frame's few dozen
    small products and, on a machine whose cores are all busy, wait for a core each time (a frame's
    25 ``torch.addmm`` took 0.7 ms alone and up to 1.4 s on a loaded 2-core machine; these 1.6 ms).
    The sums run in another order than a GEMM's: equal to :meth:`RigidObject.world` within float32
    rounding.
    """
    np.multiply(x[:, 0:1], m[:, 0], out=out)
    for k in range(1, x.shape[1]):
        out += x[:, k:k + 1] * m[:, k]
    if b is not None:
        out += b
