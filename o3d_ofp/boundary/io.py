"""Reading and writing geometries with Open3D (atomically)."""

from __future__ import annotations

import logging
import os
from typing import Any

from ..core._atomic import atomic_path
from .convert import require_open3d

__all__ = ["read_geometry", "write_geometry"]

logger = logging.getLogger(__name__)


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
    ValueError
        If Open3D cannot read it or it holds no points.
    """
    o3d = require_open3d()
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise FileNotFoundError(f"{path}: no such file")
    # Open3D prints a warning for a file with points but no triangles: that case is handled.
    with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
        mesh = o3d.io.read_triangle_mesh(path)
    if len(mesh.vertices) and len(mesh.triangles):
        return mesh
    cloud = o3d.io.read_point_cloud(path)
    if len(cloud.points):
        logger.info(
            "%s: no triangles Open3D can read (a point cloud, or e.g. PLY triangle strips): "
            "read as a point cloud of %d points",
            path,
            len(cloud.points),
        )
        return cloud
    raise ValueError(f"{path}: Open3D could not read any vertices from this file")


def write_geometry(path: str | os.PathLike[str], geometry: Any) -> None:
    """Write an Open3D mesh or point cloud atomically (temporary file, then rename).

    Parameters
    ----------
    path : str or os.PathLike
        Destination; the extension picks the format.
    geometry : open3d.geometry.TriangleMesh or open3d.geometry.PointCloud
        What to write.

    Raises
    ------
    OSError
        If Open3D fails to write; no partial file is left at ``path``.
    """
    o3d = require_open3d()
    path = os.fspath(path)
    with atomic_path(path, suffix=os.path.splitext(path)[1]) as tmp:
        # Open3D prints warnings (e.g. "OFF cannot include triangle normals") on stdout.
        with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
            if isinstance(geometry, o3d.geometry.TriangleMesh):
                ok = o3d.io.write_triangle_mesh(tmp, geometry)
            else:
                ok = o3d.io.write_point_cloud(tmp, geometry)
        if not ok:
            raise OSError(f"{path}: Open3D failed to write the file")
