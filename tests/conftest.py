"""Shared fixtures: procedural shapes, and real meshes from ../shared/data when present."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

import o3d_ofp as ofp
from o3d_ofp.core.shapes import blob, icosphere

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def shared_path(relative: str) -> Path:
    """Path of a file in ../shared/data, or skip the test with the reason."""
    path = DATA / relative
    if not path.exists():
        pytest.skip(f"research data not available: {path} (tests read ../shared/data, absent here)")
    return path


def load_shared_mesh(relative: str) -> tuple[np.ndarray, np.ndarray]:
    """(vertices, faces) of a mesh in ../shared/data, read with Open3D."""
    path = shared_path(relative)
    o3d = pytest.importorskip("open3d", reason="Open3D is needed to read the shared meshes")
    from o3d_ofp.boundary.convert import geometry_to_arrays

    vertices, faces = geometry_to_arrays(o3d.io.read_triangle_mesh(str(path)))
    return vertices, faces


@pytest.fixture(scope="session")
def stretched():
    """Make an ellipsoid and a copy stretched along x and bent (truth: the identity).

    Returns the source and target vertices, the shared faces, 6 farthest-point landmark pairs
    (each vertex with itself) and the two eigenbases of 30 functions.
    """
    from o3d_ofp.core.fmap import farthest_points

    V, F = icosphere(4)
    source = V * np.array([1.0, 0.7, 0.5])
    target = source.copy()
    target[:, 0] *= 1.4
    target[:, 1] += 0.3 * target[:, 0] ** 2
    landmarks = np.repeat(farthest_points(source, 6)[:, None], 2, axis=1)
    e1, e2 = ofp.eigenbasis(source, F, k=30), ofp.eigenbasis(target, F, k=30)
    return source, target, F, landmarks, e1, e2


@pytest.fixture(scope="session")
def sphere_mesh():
    return icosphere(5)  # 10242 vertices


@pytest.fixture(scope="session")
def sphere_eig(sphere_mesh):
    return ofp.eigenbasis(*sphere_mesh, k=24)


@pytest.fixture(scope="session")
def blob_mesh():
    return blob(4)  # 2562 vertices, no symmetry


@pytest.fixture(scope="session")
def faust_mesh():
    return load_shared_mesh("faust/tr_reg_093.ply")


@pytest.fixture(scope="session")
def faust_eig(faust_mesh):
    return ofp.eigenbasis(*faust_mesh, k=29)


@pytest.fixture
def read_only_folder(tmp_path, monkeypatch):
    """Return a folder ``os.access`` calls read-only (a root test process may write anywhere)."""
    folder = tmp_path / "ro"
    folder.mkdir()
    real = os.access
    monkeypatch.setattr(os, "access", lambda path, mode, **kw: (
        False if os.path.abspath(path) == str(folder) else real(path, mode, **kw)
    ))  # fmt: skip
    return folder
