"""UV textures of Open3D meshes: per-vertex colors sampled from the image.

Orientation conventions (measured on Open3D 0.20, see ``tests/test_texture.py``):

* UVs are OBJ/OpenGL texture coordinates everywhere (u right, v **up**), in the legacy
  ``TriangleMesh.triangle_uvs`` as in the tensor ``triangle["texture_uvs"]``; glTF files are
  converted to this convention by Open3D's readers.
* Image *files*, arrays given by the caller, ``open3d.io.read_image`` and the tensor mesh's
  ``material.texture_maps["albedo"]`` hold their rows top-down (row 0 is v = 1).
* The legacy ``TriangleMesh.textures`` hold their rows **bottom-up** (row 0 is v = 0, the
  OpenGL upload order): Open3D's legacy OBJ and glTF readers flip every image when they load
  it and the OBJ writer flips it back when it saves it. The legacy OBJ reader also puts an
  empty image first (the default material) and numbers the file's materials from 1.

:class:`MeshTexture` reads any of these into one form (top-down images, per-corner UVs, one
image index per triangle); :func:`legacy_texture_image` makes an image for
``TriangleMesh.textures`` out of a top-down array. :func:`surface_colors` reads the colors of a
mesh's surface for a bake: its texture, or for a mesh without UVs its vertex colors
(:class:`VertexColorSurface`, sampled like a texture).
"""

from __future__ import annotations

import dataclasses
import itertools
import logging
import os
from typing import Any

import numpy as np

from ..core.texture import corner_colors_to_vertices, sample_texture
from ..core.wording import AdvisedError, Said, text_of
from ._verbosity import open3d_errors_only
from .convert import geometry_kind, geometry_to_arrays, require_open3d, vertex_colors

__all__ = [
    "MeshTexture",
    "VertexColorSurface",
    "as_uint8",
    "corner_uvs",
    "has_texture_image",
    "has_uvs",
    "is_empty_image",
    "legacy_texture_image",
    "material_files",
    "mesh_texture",
    "missing_texture_files",
    "no_texture_message",
    "set_albedo",
    "surface_colors",
    "texture_colors",
    "without_texture",
]

logger = logging.getLogger(__name__)


def _image_array(image: Any) -> np.ndarray:
    """Read a top-down (H, W[, C]) array from a path, an array or an Open3D image (texture=)."""
    o3d = require_open3d()
    if isinstance(image, (str, os.PathLike)):
        path = os.fspath(image)
        if not os.path.isfile(path):
            raise FileNotFoundError(f"{path}: no such texture file")
        with open3d_errors_only():
            image = o3d.io.read_image(path)
        if is_empty_image(image):
            raise ValueError(f"{path}: Open3D could not read this image (PNG and JPEG are read)")
    if isinstance(image, o3d.t.geometry.Image):
        image = image.as_tensor().cpu().numpy()
    arr = np.array(np.asarray(image), copy=True)
    if arr.ndim == 3 and arr.shape[2] == 1:
        arr = arr[:, :, 0]
    if arr.ndim not in (2, 3) or arr.size == 0 or arr.dtype == object:
        raise ValueError(f"texture must be an (H, W[, C]) image; got shape {arr.shape}")
    return arr


def is_empty_image(image: Any) -> bool:
    """Tell an Open3D image without pixels (``np.asarray`` of one is a 0-d object array)."""
    if hasattr(image, "is_empty"):
        return bool(image.is_empty())
    return np.asarray(image).ndim < 2 or np.asarray(image).size == 0


def legacy_texture_image(image: Any) -> Any:
    """Make an image for a legacy mesh's ``textures`` out of a top-down array.

    Parameters
    ----------
    image : (H, W, C) or (H, W) array_like
        The texture as it is stored in a file (row 0 is the top of the image, v = 1); uint8 or
        float in [0, 1] (converted to uint8).

    Returns
    -------
    open3d.geometry.Image
        The same image with its rows bottom-up, the order Open3D's legacy meshes keep (their
        OBJ writer flips it back, so the written file is the right way up).
    """
    o3d = require_open3d()
    arr = np.asarray(image)
    if arr.ndim not in (2, 3) or arr.size == 0:
        raise ValueError(f"image must have shape (H, W, C) or (H, W); got {arr.shape}")
    arr = arr if np.issubdtype(arr.dtype, np.integer) else as_uint8(arr)  # ints: 0-255 as given
    return o3d.geometry.Image(np.ascontiguousarray(arr.astype(np.uint8)[::-1]))


def set_albedo(mesh: Any, image: np.ndarray) -> None:
    """Give a tensor mesh's material ``image`` (top-down rows, any dtype) as its albedo map.

    The image is stored 8-bit (:func:`as_uint8`), as Open3D's glTF writer expects.
    """
    o3d = require_open3d()
    mesh.material.set_default_properties()
    mesh.material.texture_maps["albedo"] = o3d.t.geometry.Image(
        o3d.core.Tensor(np.ascontiguousarray(as_uint8(image)))
    )


def as_uint8(image: np.ndarray) -> np.ndarray:
    """Return an image as 8-bit: integer images rescaled from their range, floats from [0, 1]."""
    if image.dtype == np.uint8:
        return image
    if np.issubdtype(image.dtype, np.integer):
        return np.round(image.astype(np.float64) / np.iinfo(image.dtype).max * 255).astype(np.uint8)
    return np.round(np.clip(image, 0.0, 1.0) * 255.0).astype(np.uint8)


@dataclasses.dataclass(frozen=True, eq=False)
class MeshTexture:
    """A textured mesh as arrays: geometry, per-corner UVs, top-down images, image per triangle.

    Attributes
    ----------
    vertices : (n, 3) ndarray of float64
        Vertex positions.
    faces : (m, 3) ndarray of int64
        Triangles.
    uvs : (m, 3, 2) ndarray of float64
        Texture coordinates of the triangle corners (u right, v up).
    images : tuple of (H, W, C) or (H, W) ndarray
        The texture images, rows top-down (as in an image file).
    material : (m,) ndarray of int64
        Index into ``images`` of each triangle's image, -1 for a triangle without one.
    """

    vertices: np.ndarray
    faces: np.ndarray
    uvs: np.ndarray
    images: tuple[np.ndarray, ...]
    material: np.ndarray

    def used_images(self) -> list[np.ndarray]:
        """Return the loaded images some triangle uses, in index order (top-down rows)."""
        used = np.unique(self.material[self.material >= 0])
        return [self.images[int(i)] for i in used if self.images[int(i)].size]

    def uv_at(self, triangles: Any, barycentric: Any) -> np.ndarray:
        """Texture coordinates of surface points.

        Parameters
        ----------
        triangles : (p,) array_like of int
            Triangle of each point.
        barycentric : (p, 3) array_like of float
            Its barycentric coordinates (weights of the triangle's corners 0, 1, 2).

        Returns
        -------
        (p, 2) ndarray of float64
            The interpolated UVs.
        """
        t = np.asarray(triangles, dtype=np.int64)
        w = np.asarray(barycentric, dtype=np.float64)
        return np.einsum("pk,pkd->pd", w, self.uvs[t])

    def sample(self, triangles: Any, barycentric: Any) -> np.ndarray:
        """RGB colors of the texture at surface points (bilinear, see ``sample_texture``).

        Parameters
        ----------
        triangles : (p,) array_like of int
            Triangle of each point.
        barycentric : (p, 3) array_like of float
            Its barycentric coordinates.

        Returns
        -------
        (p, 3) ndarray of float64
            Colors in [0, 1]; 0 on triangles without an image.
        """
        t = np.asarray(triangles, dtype=np.int64)
        return self._sample_uv(self.uv_at(t, barycentric), self.material[t])

    def _sample_uv(self, uv: np.ndarray, material: np.ndarray) -> np.ndarray:
        out = np.zeros((uv.shape[0], 3))
        for mid, img in enumerate(self.images):
            sel = material == mid
            if not np.any(sel):
                continue
            sampled = sample_texture(img, uv[sel])
            if sampled.shape[1] < 3:
                sampled = np.repeat(sampled[:, :1], 3, axis=1)
            out[sel] = sampled[:, :3]
        return np.clip(out, 0.0, 1.0)

    def corner_colors(self) -> np.ndarray:
        """(3m, 3) colors sampled at the triangle corners, in the order ``faces.reshape(-1)``."""
        return self._sample_uv(self.uvs.reshape(-1, 2), np.repeat(self.material, 3))

    def vertex_colors(self) -> np.ndarray:
        """(n, 3) colors in [0, 1] per vertex: the mean of its triangle corners' samples."""
        colors = corner_colors_to_vertices(self.faces, self.corner_colors(), self.vertices.shape[0])
        return np.clip(colors, 0, 1)


@dataclasses.dataclass(frozen=True, eq=False)
class VertexColorSurface:
    """A mesh colored per vertex, sampled like a texture (colors linear over each triangle).

    What a bake reads from a source without a texture (:func:`surface_colors`): a surface point
    in triangle (a, b, c) with barycentric weights (wa, wb, wc) has the color
    wa C(a) + wb C(b) + wc C(c).

    Attributes
    ----------
    vertices : (n, 3) ndarray of float64
        Vertex positions.
    faces : (m, 3) ndarray of int64
        Triangles.
    colors : (n, 3) ndarray of float64
        Vertex colors in [0, 1].
    """

    vertices: np.ndarray
    faces: np.ndarray
    colors: np.ndarray

    def sample(self, triangles: Any, barycentric: Any) -> np.ndarray:
        """RGB colors at surface points, interpolated from the triangle's corners.

        Parameters
        ----------
        triangles : (p,) array_like of int
            Triangle of each point.
        barycentric : (p, 3) array_like of float
            Its barycentric coordinates (weights of the triangle's corners 0, 1, 2).

        Returns
        -------
        (p, 3) ndarray of float64
            Colors in [0, 1].
        """
        t = np.asarray(triangles, dtype=np.int64)
        w = np.asarray(barycentric, dtype=np.float64)
        return np.clip(np.einsum("pk,pkd->pd", w, self.colors[self.faces[t]]), 0.0, 1.0)


def surface_colors(mesh: Any, texture: Any = None) -> MeshTexture | VertexColorSurface:
    """Read the colors of a mesh's surface for a bake: its texture, else its vertex colors.

    Parameters
    ----------
    mesh : open3d.geometry.TriangleMesh or open3d.t.geometry.TriangleMesh
        The mesh; not modified.
    texture : str, os.PathLike, ndarray or Open3D image, optional
        A texture image for the mesh's UVs (see :func:`mesh_texture`); with it the mesh's
        vertex colors are never used.

    Returns
    -------
    MeshTexture or VertexColorSurface
        The texture when the mesh has per-corner UVs (its image missing is an error, not a
        reason to fall back on vertex colors; a mesh with vertex colors too is said in the
        log), else its vertex colors.

    Raises
    ------
    ValueError
        If the mesh has UVs without a loaded image, or neither UVs nor vertex colors.
    TypeError
        If ``mesh`` is not an Open3D triangle mesh.
    """
    try:
        found = mesh_texture(mesh, texture)
        if texture is None and vertex_colors(mesh) is not None:
            logger.info(
                "the mesh has both a texture and vertex colors: its texture is used (to use "
                "its vertex colors instead, remove its triangle UVs from a copy)"
            )
        return found
    except TypeError as exc:
        raise TypeError(
            "the source must be an Open3D TriangleMesh with a texture or vertex colors (a point "
            "cloud has no surface to bake from: transfer its colors to the target's vertices "
            f"with o3d_ofp.transfer_colors); got {type(mesh).__name__}"
        ) from exc
    except ValueError as exc:
        V, F = geometry_to_arrays(mesh)
        assert F is not None  # mesh_texture refuses anything but a triangle mesh
        if texture is not None or has_uvs(mesh):
            raise
        colors = vertex_colors(mesh)
        if colors is None:
            raise ValueError(
                "the mesh has neither texture coordinates nor vertex colors: there are no "
                "colors to bake"
            ) from exc
    return VertexColorSurface(vertices=V, faces=F, colors=np.clip(colors, 0.0, 1.0))


def without_texture(geometry: Any) -> Any:
    """Return the geometry without its texture images (UVs kept), for per-vertex colors.

    A mesh given new vertex colors keeps its old texture otherwise, and what a viewer shows
    then depends on the format (Open3D's OBJ writer drops the image, its glTF writer keeps it
    and viewers multiply the two). Anything without a texture comes back as it is; the input
    is not modified.
    """
    o3d = require_open3d()
    kind = geometry_kind(geometry)
    if kind == "legacy_mesh" and has_texture_image(geometry):
        out = type(geometry)(geometry)
        out.textures = []
        out.triangle_material_ids = o3d.utility.IntVector()
        return out
    with_material = kind == "tensor_mesh" and geometry.has_valid_material()
    if with_material and len(geometry.material.texture_maps):
        out = geometry.clone()
        out.material = o3d.visualization.Material("defaultLit")
        return out
    return geometry


def has_texture_image(geometry: Any) -> bool:
    """Tell whether an Open3D mesh holds a texture image with pixels (legacy or albedo map).

    Reads no pixels. A legacy mesh's ``has_textures()`` is False while the OBJ reader's empty
    default image comes first, so the images are looked at one by one.
    """
    kind = geometry_kind(geometry)
    if kind == "legacy_mesh":
        return any(not is_empty_image(image) for image in geometry.textures)
    return kind == "tensor_mesh" and _albedo(geometry) is not None


def _albedo(mesh: Any) -> Any:
    """Return a tensor mesh's albedo map (an Open3D image), or None."""
    maps = mesh.material.texture_maps if mesh.has_valid_material() else {}
    return maps["albedo"] if "albedo" in maps else None


def has_uvs(mesh: Any) -> bool:
    """Tell whether an Open3D mesh has per-corner texture coordinates for every triangle.

    Parameters
    ----------
    mesh : Open3D geometry
        Any geometry (a point cloud has none).

    Returns
    -------
    bool
    """
    kind = geometry_kind(mesh)
    if kind == "legacy_mesh":
        return bool(mesh.has_triangle_uvs())
    if kind == "tensor_mesh":
        return "texture_uvs" in mesh.triangle or "texture_uvs" in mesh.vertex
    return False


def _no_uvs(n_uvs: int, n_faces: int) -> ValueError:
    return ValueError(
        f"the mesh has no per-corner texture coordinates ({n_uvs} UVs for {n_faces} "
        "triangles): there is no texture to sample"
    )


def no_texture_message(path: str, exc: Exception) -> Said:
    """``path: <why>``, naming the material or image files the OBJ names and lacks."""
    missing = missing_texture_files(path)
    if not missing:
        # the reason as data (a Said when it advises a fix), worded for its reader later
        why = getattr(exc, "said", None)
        return Said("{path}: {why}", {"path": path, "why": why or text_of(exc)}, "no_texture")
    return Said(
        "{path}: {files} (named by its material) not found: put the files beside it, or pass "
        "the image ({texture})", {"path": path, "files": ", ".join(missing)}, "texture_missing",
    )


def _legacy_parts(mesh: Any, n_faces: int) -> tuple[np.ndarray, list[np.ndarray], np.ndarray]:
    uv = np.array(mesh.triangle_uvs, dtype=np.float64)
    if uv.shape[0] != 3 * n_faces:
        raise _no_uvs(uv.shape[0], n_faces)
    # Legacy textures are bottom-up: flip them to the file's (top-down) orientation. Empty
    # images (the OBJ reader's default material) stay as placeholders so the ids still match.
    images = [np.zeros((0, 0)) if is_empty_image(image) else np.asarray(image)[::-1].copy()
              for image in mesh.textures]  # fmt: skip
    material = np.array(mesh.triangle_material_ids, dtype=np.int64)
    if material.shape[0] != n_faces:
        material = np.zeros(n_faces, dtype=np.int64)
    return uv.reshape(n_faces, 3, 2), images, material


def _tensor_parts(mesh: Any, faces: np.ndarray) -> tuple[np.ndarray, list[np.ndarray], np.ndarray]:
    n_faces = faces.shape[0]
    if "texture_uvs" in mesh.triangle:
        uv = np.array(mesh.triangle["texture_uvs"].cpu().numpy(), dtype=np.float64)
        if uv.shape != (n_faces, 3, 2):
            raise _no_uvs(uv.size // 2, n_faces)
    elif "texture_uvs" in mesh.vertex:  # per-vertex UVs (e.g. from a glTF file)
        uv = np.array(mesh.vertex["texture_uvs"].cpu().numpy(), dtype=np.float64)[faces]
    else:
        raise _no_uvs(0, n_faces)
    albedo = _albedo(mesh)
    images = [] if albedo is None else [np.array(albedo.as_tensor().cpu().numpy())]
    return uv, images, np.zeros(n_faces, dtype=np.int64)


def material_files(path: str | os.PathLike[str]) -> list[tuple[str, str]]:
    """Material files and texture images an OBJ names, as named and as paths.

    Only ``mtllib`` lines before the first face and ``map_Kd`` lines are read; the images of a
    material file that is not there are not known.

    Parameters
    ----------
    path : str or os.PathLike
        A ``.obj`` file (other formats, or no such file: an empty list).

    Returns
    -------
    list of (str, str)
        Each file as the OBJ or its MTL names it (relative to their folder when given so), and
        its path; in the order named, each once.
    """
    path = os.fspath(path)
    if not path.lower().endswith(".obj") or not os.path.isfile(path):
        return []
    folder = os.path.dirname(os.path.abspath(path))
    files: list[tuple[str, str]] = []
    with open(path, encoding="utf-8", errors="replace") as fh:
        head = itertools.takewhile(lambda line: not line.startswith("f "), fh)
        libraries = [line[len("mtllib ") :].strip() for line in head if line.startswith("mtllib ")]
    for lib in libraries:
        lib_path = os.path.join(folder, lib)
        files.append((lib, lib_path))
        if not os.path.isfile(lib_path):
            continue
        with open(lib_path, encoding="utf-8", errors="replace") as fh:
            # map_Kd's options (-s, -o ...) come before the file name
            images = [w[-1] for w in map(str.split, fh) if len(w) > 1 and w[0] == "map_Kd"]
        lib_folder = os.path.dirname(lib_path)
        files += [(im, os.path.join(lib_folder, im)) for im in images]
    return list(dict.fromkeys(files))


def missing_texture_files(path: str | os.PathLike[str]) -> list[str]:
    """Material files and texture images an OBJ names that are not there.

    An OBJ read without its ``.mtl`` or its images comes back with UVs and no texture, and
    Open3D says nothing: this names what is missing, for the messages that refuse such a
    source (see :func:`material_files`).

    Parameters
    ----------
    path : str or os.PathLike
        A ``.obj`` file (other formats: an empty list).

    Returns
    -------
    list of str
        The missing files, as paths relative to the OBJ's folder when they were given so.
    """
    missing = (named for named, full in material_files(path) if not os.path.isfile(full))
    return list(dict.fromkeys(missing))


def corner_uvs(mesh: Any) -> np.ndarray:
    """Copy the texture coordinates of a mesh's triangle corners (no image needed).

    Parameters
    ----------
    mesh : open3d.geometry.TriangleMesh or open3d.t.geometry.TriangleMesh
        A mesh with per-corner UVs (legacy ``triangle_uvs``, tensor ``triangle["texture_uvs"]``
        or ``vertex["texture_uvs"]``). It is not modified.

    Returns
    -------
    (m, 3, 2) ndarray of float64
        UVs of the corners of every triangle (u right, v up).

    Raises
    ------
    ValueError
        If the mesh has no UVs (or non-finite ones).
    """
    return _uv_parts(mesh)[2]


def _uv_parts(mesh: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[np.ndarray], np.ndarray]:
    """Return a mesh's vertices, faces, corner UVs, top-down images and image per triangle."""
    kind = geometry_kind(mesh)
    if kind not in ("legacy_mesh", "tensor_mesh"):
        raise TypeError("mesh must be an Open3D TriangleMesh with texture coordinates")
    V, F = geometry_to_arrays(mesh)
    assert F is not None
    parts = _legacy_parts(mesh, F.shape[0]) if kind == "legacy_mesh" else _tensor_parts(mesh, F)
    if not np.all(np.isfinite(parts[0])):
        raise ValueError("the mesh's texture coordinates hold NaN or inf")
    return (V, F, *parts)


def mesh_texture(mesh: Any, texture: Any = None) -> MeshTexture:
    """Read a mesh's UVs and texture images into a :class:`MeshTexture`.

    Parameters
    ----------
    mesh : open3d.geometry.TriangleMesh or open3d.t.geometry.TriangleMesh
        A mesh with per-corner UVs: legacy ``triangle_uvs``, or tensor
        ``triangle["texture_uvs"]`` (or ``vertex["texture_uvs"]``). It is not modified.
    texture : str, os.PathLike, (H, W[, C]) ndarray or Open3D image, optional
        The texture, rows top-down as in an image file (``open3d.io.read_image`` gives such an
        image), used for every triangle. Default: the mesh's own images, legacy ``textures``
        (chosen by ``triangle_material_ids``) or the tensor material's ``albedo`` map.

    Returns
    -------
    MeshTexture
        Copies of the geometry, UVs and images; the images top-down.

    Raises
    ------
    ValueError
        If the mesh has no UVs, or no image is given or loaded.
    """
    V, F, uv, images, material = _uv_parts(mesh)
    if texture is not None:
        images = [_image_array(texture)]
        material = np.zeros(F.shape[0], dtype=np.int64)
    filled = [i for i, im in enumerate(images) if im.ndim >= 2 and im.size > 0]
    if not filled:
        raise AdvisedError(Said(
            "the mesh has UVs but no texture image was loaded (no material file next to it?): "
            "pass the image explicitly ({texture})", {}, "no_image",
        ))  # fmt: skip
    valid = (material >= 0) & (material < len(images))
    valid[valid] = np.isin(material[valid], filled)
    if not np.all(valid):
        if len(filled) == 1:
            # e.g. material ids 0 pointing at the reader's empty default image: one real image.
            material = np.where(valid, material, filled[0])
        else:
            logger.warning(
                "texture: %d of %d triangles name no loaded image; they get black",
                int(np.count_nonzero(~valid)), F.shape[0],
            )  # fmt: skip
            material = np.where(valid, material, -1)
    return MeshTexture(
        vertices=V, faces=F, uvs=uv, images=tuple(images), material=material.astype(np.int64)
    )


def texture_colors(mesh: Any, texture: Any = None) -> np.ndarray:
    """Per-vertex RGB colors sampled from a mesh's UV texture (bilinear).

    Parameters
    ----------
    mesh : open3d.geometry.TriangleMesh or open3d.t.geometry.TriangleMesh
        A mesh with per-triangle-corner UVs (legacy ``triangle_uvs``, tensor
        ``triangle["texture_uvs"]``), e.g. read from an OBJ by ``open3d.io.read_triangle_mesh``
        or ``open3d.t.io.read_triangle_mesh``.
    texture : str, os.PathLike, ndarray or open3d.geometry.Image, optional
        The texture image, rows top-down as in an image file; default the mesh's own textures
        (loaded by Open3D from the OBJ's material file: legacy ``textures`` by material id, or
        the tensor material's albedo map). Both give the same colors: the legacy meshes' images
        are stored bottom-up and are read that way.

    Returns
    -------
    (n, 3) ndarray of float64
        Colors in [0, 1]: at each vertex, the mean of its triangle corners' samples. Open3D
        splits OBJ vertices along UV seams; the two copies of a seam vertex are welded again
        when a basis is built (see :func:`o3d_ofp.clean_shape`), so the shape stays one surface
        and the welded vertex gets the mean of both sides' colors.

    Raises
    ------
    ValueError
        If the mesh has no UVs, or no texture image is given or loaded.

    Examples
    --------
    A box with a UV map, and a texture image red on top, blue below:

    >>> import numpy as np
    >>> import open3d as o3d
    >>> import o3d_ofp as ofp
    >>> box = o3d.geometry.TriangleMesh.create_box(create_uv_map=True)
    >>> image = np.zeros((64, 64, 3), dtype=np.uint8)
    >>> image[:32, :, 0] = 255
    >>> image[32:, :, 2] = 255
    >>> colors = ofp.texture_colors(box, image)
    >>> colors.shape, bool(((colors >= 0) & (colors <= 1)).all())
    ((8, 3), True)
    """
    return mesh_texture(mesh, texture).vertex_colors()
