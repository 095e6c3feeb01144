"""Reading and writing geometries with Open3D: every read checked, every write atomic.

Open3D's readers report a damaged file (a PLY body cut short, say) only as a console warning
and return zero-filled or empty data; :func:`read_geometry` therefore checks what came back
against the file itself, and refuses (naming the vertex, face or line) coordinates that are
NaN, inf or too far apart and faces that name missing vertices. :func:`write_geometry`
writes into a temporary folder beside the destination and moves the files into place (the
geometry file last), so an OBJ's material and texture files get their final names and a
failure leaves nothing behind.
"""

from __future__ import annotations

import contextlib
import itertools
import logging
import os
import shutil
import sys
import tempfile
import threading
from collections.abc import Callable, Iterator, Sequence
from typing import Any, NamedTuple

import numpy as np

from ..core._atomic import default_file_mode
from ..core._warnings import warn
from ..core.cleaning import _MAX_SIZE, _MIN_SIZE
from ..core.wording import Said
from ._verbosity import open3d_errors_only
from .convert import geometry_to_arrays, require_open3d
from .texture import has_texture_image, is_empty_image, mesh_texture, set_albedo

__all__ = ["read_geometry", "read_if_path", "write_geometry"]

logger = logging.getLogger(__name__)

_PLY_SIZES = {
    "char": 1, "uchar": 1, "int8": 1, "uint8": 1, "short": 2, "ushort": 2, "int16": 2,
    "uint16": 2, "int": 4, "uint": 4, "int32": 4, "uint32": 4, "float": 4, "float32": 4,
    "double": 8, "float64": 8,
}  # fmt: skip


def _cut_short(path: str) -> str | None:
    """Say how a PLY file is shorter than its header announces, or None (not cut short).

    A binary body shorter than its properties' sizes (a list: at least its count per element),
    or an ASCII body with fewer data lines than elements.
    """
    fmt, counts, minimal, element = "", {}, 0, ""
    with open(path, "rb") as fh:
        for raw in itertools.islice(fh, 10000):
            words = raw.decode("ascii", errors="replace").split() or [""]
            if words[0] == "format" and len(words) > 1:
                fmt = words[1]
            elif words[0] == "element" and len(words) == 3:
                element = words[1]
                counts[element] = int(words[2]) if words[2].isdigit() else 0
            elif words[0] == "property" and element and len(words) > 1:
                kind = words[2] if words[1] == "list" and len(words) >= 5 else words[1]
                minimal += counts[element] * _PLY_SIZES.get(kind, 1)
            elif words[0] == "end_header":
                break
        else:
            return None
        header = fh.tell()
        lines = sum(1 for line in fh if line.strip()) if fmt == "ascii" else 0
    size = os.path.getsize(path)
    if fmt.startswith("binary") and size < header + minimal:
        found, announced = f"{size} bytes", f"at least {header + minimal}"
    elif fmt == "ascii" and lines < sum(counts.values()):
        found, announced = f"{lines} data lines", str(sum(counts.values()))
    else:
        return None
    return (
        f"the file is cut short ({found}; its header announces {announced}): a damaged or "
        "incomplete download"
    )


class _Contents(NamedTuple):
    """What a file holds, numbered as the file numbers it (for the messages of a bad file)."""

    vertices: np.ndarray  # (n, 3) float64
    corners: np.ndarray  # the vertex numbers the faces name, face after face
    face_of: np.ndarray  # the face number of each corner
    base: int  # the number of the first vertex and the first face (0; OBJ: 1)
    vertex_lines: Sequence[int] | None = None  # the line of each vertex in the file
    face_lines: Sequence[int] | None = None  # the line of each face


def _contents_problem(c: _Contents) -> str | None:
    """Return what makes the contents no shape, or None.

    The first of: a NaN or inf coordinate, a span whose square float64 cannot hold, a face
    naming a vertex the file does not have.
    """

    def line(lines: Sequence[int] | None, i: int) -> str:
        return "" if lines is None else f" (line {lines[i]})"

    V = c.vertices
    finite = np.isfinite(V).all(axis=1)
    if not finite.all():
        i = int(np.flatnonzero(~finite)[0])
        kind = "a NaN" if np.isnan(V[i]).any() else "an infinite"
        return f"vertex {i + c.base}{line(c.vertex_lines, i)} has {kind} coordinate"
    with np.errstate(over="ignore"):  # a span beyond float64's range is refused just below
        size = float(np.ptp(V, axis=0).max()) if len(V) else 0.0
    if size > 0 and not (_MIN_SIZE < size < _MAX_SIZE):
        problem = "overflow" if size > 1 else "underflow"
        return (
            f"the vertices span {size:.3g} units: areas (size²) would {problem} in float64; "
            "rescale the coordinates (the basis does not depend on the scale)"
        )
    bad = np.flatnonzero((c.corners < c.base) | (c.corners >= len(V) + c.base))
    if bad.size:
        face = int(c.face_of[bad[0]])
        return (
            f"face {face + c.base}{line(c.face_lines, face)} names vertex "
            f"{int(c.corners[bad[0]])}, but the file has {len(V)} vertices ({c.base}-based)"
        )
    return None


def _numbers(words: Sequence[bytes], n: int, kind: type) -> list[Any]:
    """Return the first ``n`` words as numbers of ``kind`` (ValueError if there are fewer)."""
    if len(words) < n:
        raise ValueError(f"{len(words)} numbers where {n} are needed")
    return [kind(w) for w in words[:n]]


_Rows = list[tuple[int, list[Any]]]  # (line, numbers) of each vertex or face of a text file


def _contents(vertices: _Rows, faces: _Rows, base: int) -> _Contents:
    """Return the :class:`_Contents` of a text file's vertex and face rows."""
    corners = [f for _, f in faces]
    return _Contents(
        np.array([v for _, v in vertices], dtype=np.float64).reshape(-1, 3),
        np.array([i for f in corners for i in f], dtype=np.int64),
        np.repeat(np.arange(len(corners)), [len(f) for f in corners]),
        base, [n for n, _ in vertices], [n for n, _ in faces],
    )  # fmt: skip


def _off_contents(path: str) -> _Contents:
    """Read the vertices and faces of an OFF file as it numbers them (ValueError if not)."""
    with open(path, "rb") as fh:
        rows = [(n, w) for n, line in enumerate(fh, start=1) if (w := line.split(b"#")[0].split())]
    if not rows or not rows[0][1][0].endswith(b"OFF"):
        raise ValueError("no OFF header")
    start = 1 if len(rows[0][1]) > 1 else 2  # the counts on the header's line, or the next
    n_v, n_f = _numbers(rows[0][1][1:] if start == 1 else rows[1][1], 2, int)
    vertices = [(n, _numbers(w, 3, float)) for n, w in rows[start : start + n_v]]
    faces = rows[start + n_v : start + n_v + n_f]
    return _contents(vertices, [(n, _numbers(w[1:], int(w[0]), int)) for n, w in faces], 0)


def _obj_contents(path: str, faces: bool = True) -> _Contents:
    """Read the ``v`` and (if ``faces``) ``f`` lines of an OBJ file (ValueError if it cannot)."""
    vertices: _Rows = []
    face_rows: _Rows = []
    with open(path, "rb") as fh:
        for n, line in enumerate(fh, start=1):
            words = line.split()
            if words[:1] == [b"v"]:
                vertices.append((n, _numbers(words[1:], 3, float)))
            elif words[:1] == [b"f"] and faces:
                # a negative number counts back from the last v line before the face
                k = len(vertices)
                written = [int(w.split(b"/")[0]) for w in words[1:]]
                face_rows.append((n, [k + 1 + i if -k <= i < 0 else i for i in written]))
    return _contents(vertices, face_rows, 1)


def _refuse_bad_contents(path: str, vertices: Any = None, triangles: Any = None) -> None:
    """Refuse a file whose vertices or faces make no shape, naming the first fault.

    ``vertices`` and ``triangles`` are what Open3D read (None: it read nothing usable). An OFF
    or OBJ file with a fault, or that Open3D could not read, is read again here line by line,
    so the message gives the vertex, face and line as the file numbers them (Open3D renumbers
    an OBJ's vertices, and an OFF reader that stops at a NaN leaves nothing to check).
    """
    problem = None
    if vertices is not None:
        T = np.asarray([] if triangles is None else triangles, dtype=np.int64).reshape(-1, 3)
        V = np.asarray(vertices, dtype=np.float64)
        problem = _contents_problem(_Contents(V, T.reshape(-1), np.repeat(np.arange(len(T)), 3), 0))
        if problem is None:
            return
    text_contents = {".off": _off_contents, ".obj": _obj_contents}.get(_ext(path))
    with contextlib.suppress(OSError, ValueError, IndexError):  # a file the reader cannot follow
        if text_contents is not None:
            problem = _contents_problem(text_contents(path)) or problem
    if problem is not None:
        raise ValueError(f"{path}: {problem}")


def _ext(path: str) -> str:
    return os.path.splitext(path)[1].lower()


_stderr_lock = threading.Lock()


@contextlib.contextmanager
def _reader_messages() -> Iterator[list[str]]:
    """Catch the lines Open3D's PLY reader (RPly) prints on the process's stderr in the block.

    RPly writes its errors ("RPly: Wrong magic number") with C's ``fprintf(stderr)``, out of
    reach of ``sys.stderr`` and of Open3D's verbosity level, so file descriptor 2 itself
    points to a temporary file for the block. The list yielded gets the RPly messages on
    leaving; anything else written to stderr meanwhile (by another thread) is written to it
    then. One block at a time in the process; where fd 2 cannot be duplicated, nothing is
    caught.
    """
    said: list[str] = []
    with _stderr_lock, tempfile.TemporaryFile() as tmp:
        with contextlib.suppress(AttributeError, ValueError, OSError):
            sys.stderr.flush()  # Python's pending text goes out before fd 2 is swapped
        try:
            saved = os.dup(2)
        except OSError:
            yield said
            return
        os.dup2(tmp.fileno(), 2)
        try:
            yield said
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            tmp.seek(0)
            lines = tmp.read().decode("utf-8", errors="replace").splitlines(keepends=True)
            said += [line[len("RPly: ") :].strip() for line in lines if line.startswith("RPly: ")]
            others = "".join(line for line in lines if not line.startswith("RPly: "))
            if others:
                with contextlib.suppress(OSError):
                    os.write(2, others.encode())


def _open3d_read(path: str, read: Callable[[str], Any]) -> Any:
    """Return ``read(path)``, with Open3D's console output held back.

    An error Open3D's PLY reader prints is refused instead (as a file cut short when the
    header tells so), and not printed: the reader stops at any fault of the body, so a file
    it reads in silence is whole.
    """
    ply = _ext(path) == ".ply"
    # Open3D warns on stdout about a file with points but no triangles: that case is handled.
    with open3d_errors_only(), _reader_messages() if ply else contextlib.nullcontext([]) as said:
        geometry = read(path)
    if said:
        cut = None
        with contextlib.suppress(OSError, ValueError):
            cut = _cut_short(path)
        raise ValueError(f"{path}: " + (cut or (
            f'Open3D\'s PLY reader stopped at "{said[0]}": the file is damaged, cut short, or '
            "holds a value its property's type cannot hold"
        )))  # fmt: skip
    return geometry

def read_geometry(path: str | os.PathLike[str]) -> Any:
    """Read a triangle mesh (or, when the file holds no triangles, a point cloud) with Open3D.

    Parameters
    ----------
    path : str or os.PathLike
        Any format Open3D reads (PLY, OBJ, OFF, STL, GLB, ...).

    Returns
    -------
    open3d.geometry.TriangleMesh or open3d.geometry.PointCloud
        The geometry as stored (no vertex merging or other post-processing; cleaning happens
        when a basis is built). A file whose faces Open3D cannot read (PLY triangle strips)
        comes back as a point cloud, which gets the point-cloud Laplacian.

    Raises
    ------
    FileNotFoundError
        If ``path`` does not exist.
    IsADirectoryError
        If it is a folder.
    PermissionError
        If this process may not read it.
    ValueError
        If Open3D cannot read it, it holds no points, or it is cut short (checked against the
        PLY header, since Open3D only prints a warning and fills the rest with zeros); if
        its vertices or faces make no shape: a NaN or inf coordinate, a span whose square
        float64 cannot hold, a face naming a vertex the file does not have (the message names
        the vertex or face, for OFF and OBJ with its line); if it is named .ply but is no PLY
        file. The message is one line: what Open3D's PLY reader prints is quoted, not shown.

    Examples
    --------
    >>> import os
    >>> import tempfile
    >>> import open3d as o3d
    >>> import o3d_ofp as ofp
    >>> sphere = o3d.geometry.TriangleMesh.create_sphere(radius=1.0, resolution=10)
    >>> with tempfile.TemporaryDirectory() as folder:
    ...     path = os.path.join(folder, "sphere.ply")
    ...     ofp.write_geometry(path, sphere)
    ...     mesh = ofp.read_geometry(path)
    >>> len(mesh.vertices), len(mesh.triangles)
    (182, 360)
    """
    o3d = require_open3d()
    path = os.fspath(path)
    if os.path.isdir(path):
        raise IsADirectoryError(f"{path}: a folder, not a mesh or point-cloud file")
    if not os.path.isfile(path):
        raise FileNotFoundError(f"{path}: no such file")
    if os.path.getsize(path) == 0:
        raise ValueError(f"{path}: the file is empty")
    try:  # Open3D says only "could not read any vertices" when it may not open the file
        with open(path, "rb") as fh:
            head = fh.read(4)
    except PermissionError as exc:
        raise PermissionError(f"{path}: cannot be read (permission denied)") from exc
    if _ext(path) == ".ply" and (head[:3] != b"ply" or not head[3:].isspace()):
        raise ValueError(f"{path}: not a PLY file (its first line is not 'ply')")
    mesh = _open3d_read(path, o3d.io.read_triangle_mesh)
    if len(mesh.vertices) and len(mesh.triangles):
        _refuse_bad_contents(path, mesh.vertices, mesh.triangles)
        return _in_file_order(path, mesh, o3d) if _ext(path) == ".obj" else mesh
    _refuse_bad_contents(path)  # an OFF or OBJ read without triangles: its fault, if any
    cloud = _open3d_read(path, o3d.io.read_point_cloud)
    if not len(cloud.points):
        raise ValueError(f"{path}: Open3D could not read any vertices from this file")
    _refuse_bad_contents(path, cloud.points)
    if _ext(path) in CLOUD_ONLY:  # a format of points only: nothing to explain
        logger.info("%s: a point cloud of %d points", path, len(cloud.points))
    else:
        logger.info(
            "%s: no triangles Open3D can read (a point cloud, or e.g. PLY triangle strips): "
            "read as a point cloud of %d points", path, len(cloud.points),
        )  # fmt: skip
    return cloud


def _in_file_order(path: str, mesh: Any, o3d: Any) -> Any:
    """Put an OBJ's vertices back in the order of its ``v`` lines (Open3D's reader renumbers).

    Open3D numbers an OBJ's vertices in the order the faces first use them (measured: FAUST
    087 written with UVs and read back), so per-vertex data kept beside the file (a
    registration's vertex i, a saved map) would not line up, and an OBJ written back would be
    renumbered. When the vertices are those of the ``v`` lines one to one, they are
    permuted back (the triangles, per-vertex normals and colors with them; per-corner UVs,
    textures and material ids are per triangle and stay); else (vertices split along UV
    seams) the mesh is left as read.
    """
    try:
        P = _obj_contents(path, faces=False).vertices
    except (OSError, ValueError):
        return mesh
    V = np.asarray(mesh.vertices)
    if P.shape != V.shape:
        logger.debug("%s: %d vertices read from %d v lines: Open3D's order kept", path,
                     V.shape[0], P.shape[0])  # fmt: skip
        return mesh
    # Open3D parses in single precision, not always to the nearest float: each read vertex
    # is matched to the nearest v line, within 1e-6 of the shape's size, one to one.
    from scipy.spatial import cKDTree

    size = float(np.ptp(P, axis=0).max()) or 1.0
    distance, new_of_read = cKDTree(P).query(V)  # read vertex -> its v line
    in_order = np.array_equal(new_of_read, np.arange(V.shape[0]))
    if in_order or distance.max() > 1e-6 * size or np.unique(new_of_read).size != V.shape[0]:
        return mesh  # or not one to one (repeated positions, another reader): left as read
    read_of_new = np.argsort(new_of_read)  # the inverse permutation
    out = o3d.geometry.TriangleMesh(mesh)
    out.vertices = o3d.utility.Vector3dVector(V[read_of_new])
    out.triangles = o3d.utility.Vector3iVector(new_of_read[np.asarray(mesh.triangles)])
    for name in ("vertex_normals", "vertex_colors"):
        if getattr(mesh, f"has_{name}")():
            values = np.asarray(getattr(mesh, name))[read_of_new]
            setattr(out, name, o3d.utility.Vector3dVector(values))
    logger.debug("%s: vertices put back in the order of its v lines", path)
    return out


GLTF = (".gltf", ".glb")
#: Formats Open3D writes point clouds to but not meshes: a mesh is written as its vertices.
CLOUD_ONLY = (".pcd", ".xyz", ".xyzn", ".xyzrgb", ".pts")
#: Formats that need faces: a point cloud cannot be written to them.
MESH_ONLY = (".obj", ".off", ".stl", ".glb", ".gltf")
#: Formats Open3D writes without vertex colors (checked by writing and reading back).
NO_COLORS = (".stl", ".xyz", ".xyzn")


def _as_writable(path: str, geometry: Any, o3d: Any) -> Any:
    """Return the geometry in a form Open3D can write to ``path`` (a copy if it must change).

    A mesh written to a point-cloud format becomes the cloud of its vertices (colors and
    normals kept); STL needs triangle normals, computed on a copy; a point cloud cannot be
    written to a mesh format (ValueError).
    """
    ext = _ext(path)
    kinds = (o3d.geometry.TriangleMesh, o3d.t.geometry.TriangleMesh, o3d.geometry.PointCloud,
             o3d.t.geometry.PointCloud)  # fmt: skip
    if not isinstance(geometry, kinds):
        raise TypeError(
            f"{path}: the geometry to write must be an Open3D TriangleMesh or PointCloud (legacy "
            f"or tensor); got {type(geometry).__name__} (from arrays: o3d_ofp.boundary.convert."
            "triangle_mesh_from_arrays(V, F) or point_cloud_from_arrays(V))"
        )
    if not isinstance(geometry, (o3d.geometry.TriangleMesh, o3d.t.geometry.TriangleMesh)):
        if ext in MESH_ONLY:
            raise ValueError(
                f"{path}: a point cloud has no faces and cannot be written as {ext}; write "
                f"{', '.join(('.ply', *CLOUD_ONLY))}"
            )
        return geometry
    if ext == ".obj" and isinstance(geometry, o3d.geometry.TriangleMesh):
        return _without_empty_images(geometry, o3d)
    if ext not in (*CLOUD_ONLY, ".stl"):
        return geometry
    mesh = geometry if isinstance(geometry, o3d.geometry.TriangleMesh) else geometry.to_legacy()
    if ext == ".stl":
        mesh = o3d.geometry.TriangleMesh(mesh)  # a copy: the caller's mesh is not changed
        mesh.compute_triangle_normals()
        return mesh
    logger.info("%s: the format holds points only: writing the mesh's vertices", path)
    cloud = o3d.geometry.PointCloud(mesh.vertices)
    if mesh.has_vertex_colors():
        cloud.colors = mesh.vertex_colors
    if mesh.has_vertex_normals():
        cloud.normals = mesh.vertex_normals
    return cloud


#: Formats that hold a mesh's per-corner UVs and its texture image.
TEXTURED = (".obj", *GLTF)


def _warn_lost(path: str, geometry: Any, o3d: Any) -> None:
    """Say what of the geometry the format of ``path`` cannot hold: its texture, its colors.

    Open3D's writers leave them out without a word. (Normals are not said: a reader or
    viewer computes them again from the faces.)
    """
    ext = _ext(path)
    lost = []
    if ext not in TEXTURED and has_texture_image(geometry):
        lost.append(("texture (UVs and image)", ", ".join(TEXTURED)))
    if ext in NO_COLORS and _has_colors(geometry, o3d):
        lost.append(("vertex colors", ".ply, .obj, .off, .glb, .gltf, .xyzrgb, .pcd, .pts"))
    for what, keep in lost:
        warn(logger, Said(
            "{path}: {ext} holds no {what}: the geometry is written without it ({keep} keep it)",
            {"path": path, "ext": ext, "what": what, "keep": keep}, "format_drops",
        ))  # fmt: skip


def _has_colors(geometry: Any, o3d: Any) -> bool:
    """Tell whether a mesh or point cloud (legacy or tensor) has per-vertex colors."""
    if isinstance(geometry, o3d.geometry.TriangleMesh):
        return geometry.has_vertex_colors()
    if isinstance(geometry, o3d.geometry.PointCloud):
        return geometry.has_colors()
    attributes = geometry.point if isinstance(geometry, o3d.t.geometry.PointCloud) else (
        geometry.vertex)  # fmt: skip
    return "colors" in attributes


def _without_empty_images(mesh: Any, o3d: Any) -> Any:
    """Return a legacy mesh whose texture images all have pixels (a copy if one had none).

    Open3D's OBJ reader gives a file's default material an empty image (the file's own
    texture is then image 1), and its OBJ writer stops at the first image it cannot write:
    the MTL loses every ``map_Kd`` and no image is written. Images no triangle uses are left
    out (the material ids renumbered); one some triangles use becomes a 1 x 1 white image,
    which renders as the plain white material those triangles had.
    """
    empty = [is_empty_image(image) for image in mesh.textures]
    if not any(empty):
        return mesh
    material = np.asarray(mesh.triangle_material_ids, dtype=np.int64)
    if material.shape[0] != len(mesh.triangles):
        material = np.zeros(len(mesh.triangles), dtype=np.int64)
    inside = (material >= 0) & (material < len(empty))  # (others name no image: kept as they are)
    used = np.zeros(len(empty), dtype=bool)
    used[material[inside]] = True
    kept = [i for i, e in enumerate(empty) if used[i] or not e]
    new_id = np.full(len(empty), -1, dtype=np.int64)
    new_id[kept] = np.arange(len(kept))
    white = o3d.geometry.Image(np.full((1, 1, 3), 255, dtype=np.uint8))
    out = o3d.geometry.TriangleMesh(mesh)  # a copy: the caller's mesh is not changed
    out.textures = [white if empty[i] else mesh.textures[i] for i in kept]
    ids = np.where(inside, new_id[np.clip(material, 0, len(empty) - 1)], material)
    out.triangle_material_ids = o3d.utility.IntVector(ids.astype(np.int32))
    logger.debug("%d empty texture image(s) left out or made plain white for the OBJ writer",
                 sum(empty))  # fmt: skip
    return out


def _gltf_mesh(mesh: Any, o3d: Any) -> tuple[Any, bool]:
    """(tensor mesh for Open3D's glTF writer, whether it carries a texture image).

    Open3D 0.20's legacy writer cannot be used for glTF: its ``.glb`` files cannot be read
    back (not even by Open3D: "Buffer view ... out of range") and it drops UVs and textures
    ("this file format does not support writing textures"). The tensor writer (ASSIMP) writes
    positions, normals, colors, per-corner UVs and one ``albedo`` image correctly (float32).
    """
    if isinstance(mesh, o3d.t.geometry.TriangleMesh):
        return mesh, has_texture_image(mesh) and "texture_uvs" in mesh.triangle

    V, F = geometry_to_arrays(mesh)
    out = o3d.t.geometry.TriangleMesh()
    out.vertex.positions = o3d.core.Tensor(np.ascontiguousarray(V, dtype=np.float32))
    out.triangle.indices = o3d.core.Tensor(np.ascontiguousarray(F, dtype=np.int64))
    if mesh.has_vertex_normals():
        out.vertex.normals = o3d.core.Tensor(np.asarray(mesh.vertex_normals, dtype=np.float32))
    if mesh.has_vertex_colors():
        out.vertex.colors = o3d.core.Tensor(np.asarray(mesh.vertex_colors, dtype=np.float32))
    if not mesh.has_triangle_uvs():
        return out, False
    try:
        tex = mesh_texture(mesh)
    except ValueError:  # UVs without an image: the UVs are kept
        tex = None
    uvs = np.asarray(mesh.triangle_uvs).reshape(-1, 3, 2) if tex is None else tex.uvs
    if uvs.shape[0] == F.shape[0]:
        out.triangle.texture_uvs = o3d.core.Tensor(np.ascontiguousarray(uvs, dtype=np.float32))
    used = [] if tex is None else tex.used_images()
    if len(used) > 1:
        raise ValueError(
            f"this mesh uses {len(used)} texture images; Open3D writes one image per mesh to "
            "glTF: write an .obj (OBJ + MTL + images) instead"
        )
    if used:
        set_albedo(out, used[0])
    return out, bool(used)


def _gltf_vertex_counts(mesh: Any) -> set[int]:
    """Vertex counts a glTF file of this tensor mesh may hold when read back.

    glTF has one UV per vertex: a vertex whose corners have different UVs (a seam of the
    texture atlas) is written once per UV, so the file may hold one vertex per distinct
    (vertex, UV) pair; a mesh without UVs, or without seams, keeps its count.
    """
    n = int(mesh.vertex.positions.shape[0])
    if "texture_uvs" not in mesh.triangle:
        return {n}
    corners = mesh.triangle.indices.numpy().reshape(-1)
    uvs = mesh.triangle.texture_uvs.numpy().reshape(-1, 2).astype(np.float32)  # as written
    split = int(np.unique(np.column_stack([corners, uvs]).astype(np.float64), axis=0).shape[0])
    unused = n - int(np.unique(corners).size)  # vertices in no triangle: written as they are
    return {n, split + unused}


def _check_gltf(path: str, shown: str, counts: set[int], textured: bool, o3d: Any) -> None:
    """Read a written glTF back: refuse one Open3D cannot read, or that lost its texture."""
    with open3d_errors_only():
        back = o3d.t.io.read_triangle_mesh(path)
    n = back.vertex.positions.shape[0] if "positions" in back.vertex else 0
    if n not in counts:
        written = " or ".join(str(c) for c in sorted(counts))
        problem = (
            f"Open3D wrote a glTF file it cannot read back ({n} vertices read, {written} written)"
        )
    elif textured and not has_texture_image(back):
        problem = "Open3D did not write the texture into the glTF file"
    else:
        return
    raise OSError(f"{shown}: {problem}; write .obj instead (OBJ + MTL + PNG keeps a texture)")


def _same_file(a: str, b: str) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:  # either does not exist
        return False


def write_geometry(
    path: str | os.PathLike[str],
    geometry: Any,
    *,
    protect: Sequence[str | os.PathLike[str] | None] = (),
) -> None:
    """Write an Open3D mesh or point cloud atomically.

    Everything Open3D writes (for an OBJ with a texture: the OBJ, its ``.mtl`` and the
    texture images, named after the destination) goes to a temporary folder beside the
    destination first, then each file is moved into place, the geometry file last.

    A mesh written to a point-cloud format (.pcd, .xyz, .xyzn, .xyzrgb, .pts) is written as
    its vertices (with their colors and normals); STL gets the triangle normals it needs.

    glTF (``.gltf`` with its ``.bin`` and image files beside it, or one ``.glb``) is written
    with Open3D's tensor writer, since the legacy one writes ``.glb`` files nobody can read
    and drops UVs and textures: positions (float32, the glTF type), normals, vertex colors,
    per-corner UVs and ONE texture image (as the ``albedo`` map). The file is read back to
    check it. Open3D's glTF *readers* may reorder the vertices (ASSIMP post-processing): the
    file keeps the mesh's order, but a mesh read back need not.

    Parameters
    ----------
    path : str or os.PathLike
        Destination; the extension picks the format.
    geometry : Open3D TriangleMesh or PointCloud (legacy or tensor)
        What to write.
    protect : sequence of paths, optional
        Files that must not be replaced (e.g. the inputs of a command): when the geometry
        file or a file written beside it (an OBJ's ``.mtl`` or texture images) would replace
        one of them, nothing is written. Entries that are not existing files are ignored.

    Raises
    ------
    TypeError
        For anything else than an Open3D mesh or point cloud (nothing is written).
    ValueError
        For glTF, a mesh that uses several texture images (write an OBJ instead); a point
        cloud to a mesh format (.obj, .off, .stl, .glb, .gltf); a write that would replace a
        file of ``protect``.
    OSError
        If Open3D fails to write, or writes a glTF it cannot read back (or without the
        texture); nothing is left at ``path`` or beside it.

    Warns
    -----
    OFPWarning
        When the format cannot hold the geometry's texture (anything but .obj, .glb and
        .gltf) or its vertex colors (.stl, .xyz, .xyzn): Open3D leaves them out, the message
        names the formats that keep them.

    Examples
    --------
    >>> import os
    >>> import tempfile
    >>> import open3d as o3d
    >>> import o3d_ofp as ofp
    >>> sphere = o3d.geometry.TriangleMesh.create_sphere(radius=1.0, resolution=10)
    >>> with tempfile.TemporaryDirectory() as folder:
    ...     path = os.path.join(folder, "sphere.ply")
    ...     ofp.write_geometry(path, sphere)
    ...     mesh = ofp.read_geometry(path)
    >>> len(mesh.vertices), len(mesh.triangles)
    (182, 360)
    """
    o3d = require_open3d()
    path = os.fspath(path)
    folder, name = os.path.dirname(os.path.abspath(path)), os.path.basename(path)
    writable = _as_writable(path, geometry, o3d)  # (refuses what is no Open3D geometry)
    _warn_lost(path, geometry, o3d)
    geometry = writable
    mesh = isinstance(geometry, (o3d.geometry.TriangleMesh, o3d.t.geometry.TriangleMesh))
    gltf = mesh and name.lower().endswith(GLTF)
    if gltf:
        geometry, textured = _gltf_mesh(geometry, o3d)
    legacy = isinstance(geometry, (o3d.geometry.TriangleMesh, o3d.geometry.PointCloud))
    module = o3d.io if legacy else o3d.t.io
    tmpdir = tempfile.mkdtemp(prefix=f".{name}.", dir=folder)
    try:
        tmp = os.path.join(tmpdir, name)
        # Open3D prints warnings (e.g. "OFF cannot include triangle normals") on stdout.
        with open3d_errors_only():
            ok = (module.write_triangle_mesh if mesh else module.write_point_cloud)(tmp, geometry)
        if not ok or not os.path.isfile(tmp):
            raise OSError(f"{path}: Open3D failed to write the file")
        if gltf:
            _check_gltf(tmp, path, _gltf_vertex_counts(geometry), textured, o3d)
        # the geometry file last: it refers to the others
        files = [*sorted(f for f in os.listdir(tmpdir) if f != name), name]
        _move_into_place(tmpdir, folder, files, path, [os.fspath(p) for p in protect if p])
    finally:
        shutil.rmtree(tmpdir, ignore_errors=True)


def _move_into_place(tmp: str, folder: str, files: list[str], path: str, kept: list[str]) -> None:
    """Move ``files`` from ``tmp`` into ``folder``: none if one would replace one of ``kept``."""
    for f in files:
        dest = os.path.join(folder, f)
        if any(_same_file(dest, p) for p in kept):
            raise ValueError(
                f"{path}: writing it would replace {dest}, an input: nothing was written; "
                "choose another output name"
            )
        if os.path.isdir(dest):
            raise IsADirectoryError(
                f"{path}: {dest}, written with it, is a folder: nothing was written"
            )
    mode = default_file_mode()
    created: list[str] = []  # files that did not exist: removed again if a move fails
    try:
        for f in files:
            dest = os.path.join(folder, f)
            new = not os.path.lexists(dest)
            os.chmod(os.path.join(tmp, f), mode)
            os.replace(os.path.join(tmp, f), dest)
            if new:
                created.append(dest)
    except OSError:
        for dest in created:
            with contextlib.suppress(OSError):
                os.remove(dest)
        raise


class MissingFileError(FileNotFoundError, ValueError):
    """A file path given for a shape names no file: both errors, as callers catch either."""


def read_if_path(shape: Any, name: str) -> Any:
    """Return the geometry read from ``shape`` if it is a file path (str or PathLike), else it.

    ``name`` (e.g. "source") starts the message of the error for a file that cannot be read: a
    ValueError, which for a missing file is a FileNotFoundError too (:class:`MissingFileError`).
    """
    if isinstance(shape, (str, os.PathLike)):
        try:
            return read_geometry(shape)
        except FileNotFoundError as exc:
            raise MissingFileError(f"{name}: {exc}") from exc
        except (OSError, ValueError) as exc:
            raise ValueError(f"{name}: {exc}") from exc
    return shape
