"""Signals named by ``--signal`` and writing per-vertex results."""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import Any

import numpy as np

from ..boundary.convert import like_target, vertex_colors
from ..boundary.io import NO_COLORS, write_geometry
from ..boundary.texture import has_uvs, no_texture_message, texture_colors, without_texture
from ..core._atomic import atomic_path
from ..core.wording import text_of
from ..render.panel import colormap
from ._common import UsageError, check_output, load_npy


def read_signal(geometry: Any, V: np.ndarray, path: str, spec: str, texture: str | None, *,
                output: str | None = None) -> tuple[np.ndarray, str]:  # fmt: skip
    """(values (n,) or (n, d), kind) of ``--signal`` on the geometry read from ``path``.

    With ``output`` (the ``-o`` path), colors bound for a format that holds none (STL, XYZ)
    are refused here, before any work: they would be dropped without a word.
    """
    if texture is not None and spec != "texture":
        if not has_uvs(geometry):
            raise UsageError(f"--texture {texture}: {path} has no texture coordinates (UVs) to map "
                             "an image onto; drop --texture")  # fmt: skip
        raise UsageError("--texture applies to --signal texture")
    if texture is not None and not os.path.isfile(texture):
        raise UsageError(f"--texture {texture}: no such image file")
    if spec == "xyz":
        return V, "xyz"
    if spec.endswith(".npy"):
        f = load_npy(spec, "per-vertex signal", flag="--signal")
        if f.ndim not in (1, 2) or f.shape[0] != V.shape[0]:
            raise UsageError(f"--signal {spec}: has shape {f.shape} but {path} has {V.shape[0]} "
                             "vertices (expected (n,) or (n, d))")  # fmt: skip
        if not np.all(np.isfinite(f)):
            raise UsageError(f"--signal {spec}: must hold finite numbers")
        return f.astype(np.float64), "array"
    if spec not in ("colors", "texture"):
        raise UsageError(f"--signal must be colors, texture, xyz or a FILE.npy; got {spec!r}")
    colors = vertex_colors(geometry) if spec == "colors" else None
    if spec == "colors" and colors is None:
        hint = ("it has texture coordinates: use --signal texture" if has_uvs(geometry) else
                "transfer its coordinates with --signal xyz, or a per-vertex signal with --signal "
                "FILE.npy")  # fmt: skip
        raise UsageError(f"{path}: has no vertex colors ({hint})")
    try:
        colors = texture_colors(geometry, texture) if colors is None else colors
    except (ValueError, TypeError, FileNotFoundError) as exc:
        raise texture_error(path, texture, exc) from exc
    check_colors_output(output)
    return colors, "colors"


def check_colors_output(output: str | None) -> None:
    """Refuse colors bound for an ``-o`` format that holds none (STL, XYZ), before any work."""
    ext = os.path.splitext(output or "")[1].lower()
    if ext in NO_COLORS:
        raise UsageError(f"-o {output}: {ext} holds no vertex colors, so the colors would be lost; "
                         "write .ply, .obj, .off, .glb or .gltf (meshes), or .xyzrgb, .pcd, .pts "
                         "(points)")  # fmt: skip


def texture_error(path: str, texture: str | None, exc: Exception) -> UsageError:
    """Return the error of a texture that cannot be read (``--texture FILE``, or the source's).

    The source's own names the files its material lacks.
    """
    if texture is not None:  # the given image, not the source, is at fault
        return UsageError(f"--texture {texture}: "
                          + text_of(exc, cli=True).removeprefix(f"{texture}: "))  # fmt: skip
    return UsageError(no_texture_message(path, exc))


def _save_npy(path: str, values: np.ndarray) -> None:
    with atomic_path(path, suffix=".npy") as tmp:
        np.save(tmp, values)


def side_outputs(path: str, kind: str) -> list[str]:
    """Files besides ``path`` that :func:`write_result` writes for a signal of ``kind``."""
    if kind == "array" and not path.lower().endswith(".npy"):
        return [os.path.splitext(path)[0] + ".npy"]
    return []


def signal_sides(args: Any) -> list[str]:
    """Side files of ``-o`` known from the flags: the ``.npy`` of a ``--signal FILE.npy``."""
    signal = getattr(args, "signal", None)
    npy = isinstance(signal, str) and signal.lower().endswith(".npy")
    return side_outputs(args.output, "array") if npy else []


def write_result(path: str, like: Any, values: np.ndarray, kind: str, *,
                 protect: Sequence[str | None] = ()) -> list[str]:  # fmt: skip
    """Write ``values`` on a copy of the geometry ``like``: colored, moved, or a ``.npy``.

    A colored copy has no texture image (its UVs are kept): the colors replace it. Returns
    the files written. A general signal goes to a ``.npy`` beside the geometry, which
    shows its first channel through a colormap. Nothing is written when a file would replace
    one of ``protect`` (the command's inputs).
    """
    sides = side_outputs(path, kind)
    for side in sides:
        check_output(side, (".npy",), inputs=protect, flag="-o (its .npy beside it)")
    if path.lower().endswith(".npy"):
        _save_npy(path, values)
        return [path]
    if kind == "xyz":
        out = like_target(like, vertices=values)
    elif kind == "colors" or (values.ndim == 2 and values.shape[1] == 3):
        out = without_texture(like_target(like, colors=np.clip(values, 0.0, 1.0)))
    else:
        first = values.reshape(len(values), -1)[:, 0]
        out = without_texture(like_target(like, colors=colormap(first)))
    for npy in sides:
        _save_npy(npy, values)
    write_geometry(path, out, protect=protect)
    return [path, *sides]
