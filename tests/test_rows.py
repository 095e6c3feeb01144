"""``unique_rows`` gives exactly what ``np.unique(rows, axis=0)`` gives, on every path."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from o3d_ofp.core._rows import unique_rows
from o3d_ofp.core.geometry import fold_cosines, interior_edges, unique_edges
from o3d_ofp.core.shapes import icosphere

RNG = np.random.default_rng(7)
_F = icosphere(3)[1]
CASES = {
    # few values per column: the offsets of every column make the keys
    "edges of a mesh": np.sort(
        np.concatenate([_F[:, [0, 1]], _F[:, [1, 2]], _F[:, [2, 0]]]), axis=1
    ),
    "small, with negatives": RNG.integers(-3, 3, size=(400, 2)),
    "one column, int32": RNG.integers(0, 7, size=(50, 1)).astype(np.int32),
    "one row": RNG.integers(0, 3, size=(1, 3)),
    # columns spanning more values than there are rows (grid cells): their ranks
    "wide columns, repeated rows": np.repeat(RNG.integers(0, 10**9, size=(3000, 3)), 2, axis=0)[
        RNG.permutation(6000)
    ],
    "huge values": RNG.integers(-(2**62), 2**62, size=(300, 3)),
    # keys that cannot fit in int64 (3**40 of them): the lexicographic sort
    "forty columns": RNG.integers(0, 3, size=(2000, 40)),
    "empty": np.zeros((0, 3), dtype=np.int64),
}


@pytest.mark.parametrize("name", CASES)
@pytest.mark.parametrize("flags", list(itertools.product((False, True), repeat=3)))
def test_unique_rows_is_np_unique_along_rows(name, flags):
    rows = CASES[name]
    options = dict(zip(("return_index", "return_inverse", "return_counts"), flags, strict=True))
    expected = np.unique(rows, axis=0, **options)
    got = unique_rows(rows, **options)
    expected = expected if isinstance(expected, tuple) else (expected,)
    got = got if isinstance(got, tuple) else (got,)
    assert len(got) == len(expected)
    for e, g in zip(expected, got, strict=True):
        # NumPy 2.0 shaped the inverse of an axis=0 unique as (n, 1) for a while: compare values
        np.testing.assert_array_equal(g, np.asarray(e).reshape(g.shape))
        assert g.dtype == np.asarray(e).dtype
    if options["return_index"] and rows.shape[0]:  # first occurrences, not any occurrence
        index = got[1]
        assert all(not (rows[:i] == rows[i]).all(axis=1).any() for i in index)


def test_unique_rows_refuses_what_is_not_integer_rows():
    with pytest.raises(TypeError, match="2-D integer"):
        unique_rows(np.zeros((3, 2)))
    with pytest.raises(TypeError, match="2-D integer"):
        unique_rows(np.arange(4))


def test_unique_edges_counts_each_edge_of_a_closed_mesh_twice():
    V, F = icosphere(2)
    edges, counts = unique_edges(F)
    assert edges.shape[0] == 3 * F.shape[0] // 2  # closed: every edge in two triangles
    assert (counts == 2).all()
    assert V.shape[0] - edges.shape[0] + F.shape[0] == 2  # Euler characteristic of a sphere


def test_interior_edges_pair_each_shared_edge_with_its_two_triangles():
    """A regular tetrahedron, a fan with boundary edges and a fin on three triangles."""
    s = 1.0 / np.sqrt(2.0)
    V = np.array([[1, 0, -s], [-1, 0, -s], [0, 1, s], [0, -1, s]], dtype=float)
    F = np.array([[0, 1, 2], [0, 3, 1], [0, 2, 3], [1, 3, 2]])  # outward
    edges, sides = interior_edges(F)
    assert edges.shape == (6, 2) and sides.shape == (6, 2)
    for (a, b), (f, g) in zip(edges, sides, strict=True):  # both triangles hold the edge
        assert f != g and {a, b} <= set(F[f]) and {a, b} <= set(F[g])
    # outward normals of two faces of a regular tetrahedron: 180° minus its dihedral angle
    assert np.allclose(fold_cosines(V, F, sides), -1.0 / 3.0)
    # an open fan: its rim edges have one triangle; a fin (edge 0-1 in three): left out
    fan = np.array([[0, 1, 2], [0, 2, 3], [0, 3, 4]])
    assert interior_edges(fan)[0].tolist() == [[0, 2], [0, 3]]
    fin = np.array([[0, 1, 2], [0, 1, 3], [1, 0, 4], [1, 2, 5]])
    assert interior_edges(fin)[0].tolist() == [[1, 2]]
    # a flat pair and the same folded back onto itself
    flat = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], dtype=float)
    pair = np.array([[0, 1, 2], [1, 3, 2]])
    assert np.allclose(fold_cosines(flat, pair, interior_edges(pair)[1]), 1.0)
    back = flat.copy()
    back[3] = [-1, -1, 1e-9]
    assert fold_cosines(back, pair, interior_edges(pair)[1])[0] < -0.99
