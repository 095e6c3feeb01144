"""UV textures of Open3D meshes: per-vertex colors sampled from the image."""

from __future__ import annotations

import logging
import os
from types import ModuleType
from typing import Any

import numpy as np

from ..core.texture import corner_colors_to_vertices, sample_texture
from .convert import geometry_kind, geometry_to_arrays, require_open3d

__all__ = ["texture_colors"]

logger = logging.getLogger(__name__)


def _image_array(image: Any, o3d: ModuleType, name: str) -> np.ndarray:
    if isinstance(image, (str, os.PathLike)):
        path = os.fspath(image)
        if not os.path.isfile(path):
            raise FileNotFoundError(f"{path}: no such texture file")
        with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
            image = o3d.io.read_image(path)
        if np.asarray(image).size == 0:
            raise ValueError(f"{path}: Open3D could not read this image (PNG and JPEG are read)")
    arr = np.array(np.asarray(image), copy=True)
    if arr.ndim not in (2, 3) or arr.size == 0:
        raise ValueError(f"{name} must be an (H, W[, C]) image; got shape {arr.shape}")
    return arr


def texture_colors(mesh: Any, texture: Any = None) -> np.ndarray:
    """Per-vertex RGB colors sampled from a mesh's UV texture (bilinear).

    Parameters
    ----------
    mesh : open3d.geometry.TriangleMesh (or ``open3d.t.geometry.TriangleMesh``)
        A mesh with per-triangle-corner UVs (``triangle_uvs``), e.g. read from an OBJ.
    texture : str, os.PathLike, ndarray or open3d.geometry.Image, optional
        The texture image; default the mesh's own textures (loaded by Open3D from the OBJ's
        material file), one per material id.

    Returns
    -------
    (n, 3) ndarray of float64
        Colors in [0, 1]: at each vertex, the mean of its triangle corners' samples. Open3D
        splits OBJ vertices along UV seams; the two copies of a seam vertex are welded again
        when a basis is built (see :mod:`o3d_ofp.cleaning`), so the shape stays one surface
        and the welded vertex gets the mean of both sides' colors.

    Raises
    ------
    ValueError
        If the mesh has no UVs, or no texture image is given or loaded.
    """
    o3d = require_open3d()
    if geometry_kind(mesh) == "tensor_mesh":
        mesh = mesh.to_legacy()
    if geometry_kind(mesh) != "legacy_mesh":
        raise TypeError("mesh must be an Open3D TriangleMesh with texture coordinates")
    V, F = geometry_to_arrays(mesh)
    uv = np.array(mesh.triangle_uvs, dtype=np.float64)
    if uv.shape[0] != 3 * F.shape[0]:
        raise ValueError(
            f"the mesh has no per-corner texture coordinates ({uv.shape[0]} UVs for "
            f"{F.shape[0]} triangles): there is no texture to sample"
        )
    if texture is not None:
        images = [_image_array(texture, o3d, "texture")]
        material = np.zeros(F.shape[0], dtype=np.int64)
    else:
        images = [np.array(np.asarray(t), copy=True) for t in mesh.textures]
        if not images or all(im.size == 0 for im in images):
            raise ValueError(
                "the mesh has UVs but no texture image was loaded (no material file next to "
                "it?): pass the image explicitly (texture=... / --texture FILE)"
            )
        material = np.array(mesh.triangle_material_ids, dtype=np.int64)
        if material.shape[0] != F.shape[0]:
            material = np.zeros(F.shape[0], dtype=np.int64)
    corners = np.zeros((3 * F.shape[0], 3))
    corner_material = np.repeat(material, 3)
    for mid, img in enumerate(images):
        sel = corner_material == mid
        if not np.any(sel) or img.size == 0:
            continue
        sampled = sample_texture(img, uv[sel])
        if sampled.shape[1] == 1:
            sampled = np.repeat(sampled, 3, axis=1)
        corners[sel] = sampled[:, :3]
    return np.clip(corner_colors_to_vertices(F, corners, V.shape[0]), 0.0, 1.0)
