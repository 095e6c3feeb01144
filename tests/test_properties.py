"""Property-based tests: random small meshes and arrays see only the documented exceptions.

Every entry point must answer arbitrary input with a result or a ``ValueError``/``TypeError``
(``EigenSolverError`` for a solver failure): no other exception, no crash (Open3D and
robust-laplacian do no bounds checks), no hang, and no mutation of the caller's arrays.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

import o3d_ofp as ofp
from o3d_ofp.core.cleaning import clean_shape
from o3d_ofp.core.shapes import icosphere

DOCUMENTED = (ValueError, TypeError, ofp.EigenSolverError)

finite_coords = st.floats(-10.0, 10.0, allow_nan=False, width=64)
nasty_coords = st.one_of(
    finite_coords,
    st.sampled_from([np.nan, np.inf, -np.inf, 1e300, -1e300, 1.7e308, -1.7e308, 1e-300, 0.0]),
    st.floats(allow_nan=True, allow_infinity=True),
)


@st.composite
def meshes(draw, coords=finite_coords):
    """(vertices, faces) with repeated vertices, random (possibly bad) faces and dtypes."""
    n = draw(st.integers(0, 14))
    V = draw(hnp.arrays(np.float64, (n, 3), elements=coords))
    if n and draw(st.booleans()):  # repeat some vertices
        V = np.concatenate([V, V[draw(st.lists(st.integers(0, n - 1), max_size=5))]])
    n = V.shape[0]
    m = draw(st.one_of(st.just(0), st.integers(1, 20)))
    F = draw(hnp.arrays(np.int64, (m, 3), elements=st.integers(-2, max(n + 1, 1))))
    dtype = draw(st.sampled_from([np.int64, np.int32, np.uint32, np.float64]))
    with np.errstate(invalid="ignore"):
        F = F.astype(dtype)
    if draw(st.booleans()) and n:  # faces that are in range
        F = draw(hnp.arrays(np.int64, (m, 3), elements=st.integers(0, n - 1)))
    return V, F


def _run_pipeline(V, F, k, order):
    V0, F0 = V.copy(), None if F is None else F.copy()
    try:
        eig = ofp.eigenbasis(V, F, k=k)
        B = ofp.ofp_basis(eig, order=order)
        assert B.Q.shape[0] == V.shape[0]
        assert np.all(np.isfinite(B.Q))
        f = np.arange(V.shape[0], dtype=np.float64)
        assert B.reconstruct(B.project(f)).shape == f.shape
    except DOCUMENTED:
        pass
    np.testing.assert_array_equal(V, V0)  # NaN-aware: the input is never modified
    if F is not None:
        np.testing.assert_array_equal(F, F0)


COMMON = settings(
    max_examples=60,
    deadline=None,  # first calls import robust-laplacian; the suite's time is bounded anyway
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
    derandomize=True,  # the same examples in every CI run
)


@COMMON
@given(meshes(), st.integers(-1, 6), st.integers(1, 3))
def test_random_meshes_give_a_basis_or_a_documented_error(mesh, k, order):
    _run_pipeline(*mesh, k, order)


@COMMON
@given(meshes(coords=nasty_coords), st.integers(1, 4))
def test_nan_inf_huge_and_tiny_coordinates(mesh, k):
    _run_pipeline(*mesh, k, 2)


@COMMON
@given(
    hnp.arrays(np.float64, st.tuples(st.integers(0, 30), st.just(3)), elements=nasty_coords),
    st.integers(1, 5),
)
def test_random_point_clouds(points, k):
    _run_pipeline(points, None, k, 2)


@COMMON
@given(
    st.one_of(
        st.none(),
        st.text(max_size=3),
        st.lists(st.floats(), max_size=4),
        hnp.arrays(
            st.sampled_from([np.float64, np.int8, np.bool_, np.complex128, np.uint8]),
            hnp.array_shapes(min_dims=0, max_dims=3, max_side=4),
        ),
    ),
    st.one_of(st.none(), hnp.arrays(np.int64, hnp.array_shapes(max_dims=3, max_side=4))),
)
def test_wrong_types_and_shapes(vertices, faces):
    try:
        ofp.eigenbasis(vertices, faces, k=1)
    except DOCUMENTED:
        pass


@COMMON
@given(meshes(), st.integers(0, 3))
def test_duplicated_vertices_map_back_to_their_representative(mesh, extra):
    V, F = mesh
    try:
        shape = clean_shape(V, F)
    except DOCUMENTED:
        return
    c = shape.cleaning
    # Every input vertex maps to a cleaned vertex at the same position (within the welding
    # tolerance) when it is kept, and the cleaned faces only use cleaned vertices.
    kept = c.kept
    size = float(np.max(np.ptp(V, axis=0)))
    dist = np.abs(V[kept] - shape.vertices[c.index[kept]]).max(initial=0.0)
    assert dist <= 2e-9 * size
    assert c.index.min() >= 0 and c.index.max() < shape.vertices.shape[0]
    if shape.faces is not None:
        assert shape.faces.max() < shape.vertices.shape[0]


@st.composite
def damaged_spheres(draw):
    """Damage a small icosphere the ways real files are: holes, duplicates, strays, scale."""
    V, F = icosphere(1)  # 42 vertices, 80 faces
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    F = F[rng.random(len(F)) >= draw(st.sampled_from([0.0, 0.05, 0.3]))]  # holes
    n_dup = draw(st.integers(0, 20))
    dup = rng.integers(0, len(V), n_dup)
    V = np.concatenate([V, V[dup]])
    for i, v in enumerate(dup):  # re-point some faces to the copies
        rows = np.flatnonzero(np.any(F == v, axis=1))
        if rows.size:
            r = rows[rng.integers(0, rows.size)]
            F[r] = np.where(F[r] == v, 42 + i, F[r])
    n_extra = draw(st.integers(0, 3))  # random extra faces: non-manifold, degenerate, strays
    V = np.concatenate([V, rng.standard_normal((draw(st.integers(0, 4)), 3)) * 3])
    if len(F) + n_extra:
        F = np.concatenate([F, rng.integers(0, len(V), (n_extra, 3))]).astype(np.int64)
    V = V * 10.0 ** draw(st.integers(-60, 60))
    perm = rng.permutation(len(V))
    inverse = np.argsort(perm)
    return V[perm], inverse[F]


@COMMON
@given(damaged_spheres(), st.integers(1, 8))
def test_damaged_meshes(mesh, k):
    V, F = mesh
    try:
        eig = ofp.eigenbasis(V, F, k=k)
    except DOCUMENTED:
        return
    # A basis that exists is a meaningful one: one zero eigenvalue, M-orthonormal functions on
    # every input vertex.
    assert eig.evecs.shape == (len(V), k + 1)
    assert eig.evals[0] == 0.0 and eig.evals[1] > 0
    B = ofp.ofp_basis(eig)
    gram = B.Q.T @ (B.mass[:, None] * B.Q)
    assert np.abs(gram - np.eye(gram.shape[0])).max() < 1e-8


def test_open3d_geometries_with_bad_indices_are_refused_before_open3d_sees_them():
    o3d = pytest.importorskip("open3d")
    from o3d_ofp.boundary.convert import geometry_to_arrays

    rng = np.random.default_rng(0)
    V = rng.standard_normal((10, 3))
    mesh = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(V), o3d.utility.Vector3iVector(np.array([[0, 1, 50]]))
    )
    with pytest.raises(ValueError, match="out of range"):
        geometry_to_arrays(mesh)
    with pytest.raises(ValueError, match="out of range"):
        ofp.transfer_colors(mesh, mesh)
