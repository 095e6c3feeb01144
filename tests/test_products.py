import math

import numpy as np
import pytest

from o3d_ofp.core.products import (
    eigenproduct_blocks,
    eigenproduct_indices,
    eigenproducts,
    n_eigenproducts,
)

from ._reference import eigenproducts_naive


@pytest.mark.parametrize(("k", "order"), [(1, 1), (3, 1), (8, 2), (5, 3), (4, 4), (3, 6)])
def test_count_order_and_values_match_naive(k, order):
    rng = np.random.default_rng(k * 10 + order)
    evecs = rng.standard_normal((50, k + 1))
    P, idx = eigenproducts(evecs, order)
    assert P.shape == (50, math.comb(k + order, order)) == (50, n_eigenproducts(k, order))
    ref, ref_idx = eigenproducts_naive(evecs, order)
    assert idx == ref_idx
    # graded lexicographic: by degree, then lexicographically
    assert idx == sorted(idx, key=lambda t: (len(t), t))
    assert idx[0] == () and idx[1 : k + 1] == [(i,) for i in range(1, k + 1)]
    np.testing.assert_allclose(P, ref, rtol=1e-13, atol=0)
    np.testing.assert_array_equal(P[:, 0], evecs[:, 0])


@pytest.mark.parametrize("block_size", [1, 7, 64, 1000])
def test_blocks_tile_the_matrix(block_size):
    evecs = np.random.default_rng(0).standard_normal((30, 7))
    # eigenproducts() is assembled from eigenproduct_blocks(): compare with the naive
    # enumeration instead, which shares no code with either.
    ref, _ = eigenproducts_naive(evecs, 3)
    starts, cols = [], []
    for start, block in eigenproduct_blocks(evecs, 3, block_size=block_size):
        assert block.shape == (30, min(block_size, ref.shape[1] - start)) and block.shape[1] > 0
        starts.append(start)
        cols.append(block)
    # consecutive blocks starting at column 0, covering every candidate exactly once
    np.testing.assert_array_equal(starts, np.cumsum([0] + [c.shape[1] for c in cols[:-1]]))
    tiled = np.concatenate(cols, axis=1)
    assert tiled.shape == ref.shape
    np.testing.assert_allclose(tiled, ref, rtol=1e-13, atol=0)


def test_indices_for_large_order_do_not_build_a_tensor():
    idx = eigenproduct_indices(29, 3)
    assert len(idx) == math.comb(32, 3) == 4960
    assert idx[-1] == (29, 29, 29)


def test_bad_arguments():
    with pytest.raises(ValueError, match="order must be >= 1"):
        eigenproducts(np.ones((5, 3)), 0)
    with pytest.raises(TypeError, match="order must be an integer"):
        eigenproducts(np.ones((5, 3)), 2.0)
    with pytest.raises(ValueError, match=r"evecs must have shape \(n, k\+1\)"):
        eigenproducts(np.ones(5), 2)
