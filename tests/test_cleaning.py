"""Real-world input: welding, stray components, point clouds, limits, and the nasty/ files."""

from __future__ import annotations

import logging

import numpy as np
import pytest

import o3d_ofp as ofp
from o3d_ofp.core import _memory
from o3d_ofp.core._warnings import warnings_logged
from o3d_ofp.core.cleaning import AUTO_KEEP_FRACTION, check_shape, clean_shape
from o3d_ofp.core.laplacian import laplacian
from o3d_ofp.core.shapes import blob, icosphere
from o3d_ofp.workflows.pipeline import transfer_function

from .conftest import DATA, shared_path


def _mass_gram(eig):
    return eig.evecs.T @ (eig.mass[:, None] * eig.evecs)


def _soup(V, F):
    """Every triangle with its own three vertices, as an STL file stores a mesh."""
    return V[F.reshape(-1)], np.arange(3 * F.shape[0]).reshape(-1, 3)


def _check_meaningful(eig, n_input, k):
    """Check the issue's "meaningful basis": one zero eigenvalue, outputs on the input."""
    assert eig.evecs.shape == (n_input, k + 1)
    # Exactly one eigenvalue at 0; the next one is a real frequency (relative to λ_k; a
    # second component would give ~1e-12 here).
    assert eig.evals[0] == 0.0
    assert eig.evals[1] > 1e-6 * eig.evals[-1]
    B = ofp.ofp_basis(eig)
    assert B.Q.shape[0] == n_input
    assert B.Q.shape[1] > k + 1  # more functions than eigenfunctions
    gram = B.Q.T @ (B.mass[:, None] * B.Q)
    assert np.abs(gram - np.eye(gram.shape[0])).max() < 1e-10
    return B


def test_triangle_soup_is_welded_and_matches_the_mesh():
    V, F = blob(3)  # 642 vertices
    Vs, Fs = _soup(V, F)
    # What a naive pipeline sees: one component per triangle, so the Laplacian's smallest
    # eigenvalues are all zero (no frequencies at all).
    L, M = laplacian(Vs, Fs)
    small = np.linalg.eigvalsh(np.diag(1 / np.sqrt(M)) @ L.toarray() @ np.diag(1 / np.sqrt(M)))
    assert np.abs(small[:30]).max() < 1e-8
    with pytest.raises(ValueError, match=f"{F.shape[0]} connected components"):
        ofp.eigenbasis(Vs, Fs, k=10, weld_tolerance=None)

    eig = ofp.eigenbasis(Vs, Fs, k=10)
    ref = ofp.eigenbasis(V, F, k=10)
    report = eig.cleaning.report
    assert report.merged_vertices == Vs.shape[0] - V.shape[0]
    assert (report.vertices, report.faces) == (V.shape[0], F.shape[0])
    _check_meaningful(eig, Vs.shape[0], 10)
    np.testing.assert_allclose(eig.evals, ref.evals, rtol=1e-9, atol=1e-12)
    # Every soup vertex carries the value of the mesh vertex it copies (signs are
    # deterministic, eigenvalues simple on the blob).
    np.testing.assert_allclose(eig.evecs, ref.evecs[F.reshape(-1)], atol=1e-8)
    assert np.abs(_mass_gram(eig) - np.eye(11)).max() < 1e-10
    assert eig.area == pytest.approx(ref.area, rel=1e-12)


def test_degenerate_duplicated_faces_and_unreferenced_vertices():
    V, F = icosphere(2)
    extra_v = np.concatenate([V, [[5.0, 5.0, 5.0]], V[:1]])  # one stray, one duplicate of 0
    n = V.shape[0]
    F2 = np.concatenate(
        [
            F,
            F[:3, ::-1],  # duplicated faces, reversed orientation
            [[0, 0, 1], [0, n + 1, 2]],  # degenerate (the second only after welding)
        ]
    )
    F2 = np.where(F2 == 0, n + 1, F2)  # faces use the duplicate of vertex 0 instead
    F2[0, 0] = 0
    shape = clean_shape(extra_v, F2)
    r = shape.cleaning.report
    assert (r.merged_vertices, r.unreferenced_vertices) == (1, 1)
    assert (r.duplicate_faces, r.degenerate_faces) == (3, 2)
    assert (r.vertices, r.faces) == (n, F.shape[0])
    eig = ofp.eigenbasis(extra_v, F2, k=8)
    ref = ofp.eigenbasis(V, F, k=8)
    np.testing.assert_allclose(eig.evals, ref.evals, rtol=1e-9)
    assert eig.mass[n] == 0.0  # the stray vertex carries no mass...
    nearest = np.argmin(np.linalg.norm(V - [5.0, 5.0, 5.0], axis=1))
    np.testing.assert_allclose(eig.evecs[n], eig.evecs[nearest])  # ...and nearest values
    np.testing.assert_allclose(eig.evecs[n + 1], eig.evecs[0])  # the duplicate: vertex 0's
    assert "welded 1 duplicated vertices" in str(r)


def test_tiny_stray_component_is_dropped_with_a_warning(caplog):
    V, F = icosphere(3)
    stray_v = np.array([[3.0, 0, 0], [3.01, 0, 0], [3.0, 0.01, 0]])
    V2 = np.concatenate([V, stray_v])
    F2 = np.concatenate([F, [[len(V), len(V) + 1, len(V) + 2]]])
    with caplog.at_level(logging.WARNING, logger="o3d_ofp.core.cleaning"), warnings_logged():
        with pytest.warns(ofp.OFPWarning, match="kept the largest of 2 components"):
            eig = ofp.eigenbasis(V2, F2, k=8)
    assert "kept the largest of 2 components" in caplog.text
    # the left-out vertices are still in the results (a trial read "dropping" as removed)
    assert "stay in the results with the values of their nearest kept vertex" in caplog.text
    # the share is of the area (3 of 645 vertices but a far smaller share of the area; a
    # trial read "% of the total" as a share of the vertices)
    assert "leaves out 3 vertices (" in caplog.text and " % of the area)" in caplog.text
    _check_meaningful(eig, V2.shape[0], 8)
    assert np.all(eig.mass[len(V) :] == 0)
    # The stray vertices take the values of the nearest sphere vertex (the one at x = 1).
    tip = np.argmax(V[:, 0])
    np.testing.assert_allclose(eig.evecs[len(V) :], np.repeat(eig.evecs[[tip]], 3, axis=0))
    with pytest.raises(ValueError, match="2 connected components"):
        ofp.eigenbasis(V2, F2, k=8, components="error")
    with pytest.raises(ValueError, match="components must be one of"):
        ofp.eigenbasis(V2, F2, k=8, components="all")


def test_comparable_components_need_an_explicit_choice():
    V, F = icosphere(2)
    small = 0.5 * V + [4.0, 0, 0]  # a quarter of the area: more than 1 - AUTO_KEEP_FRACTION
    V2, F2 = np.concatenate([V, small]), np.concatenate([F, F + len(V)])
    assert 0.2 > 1 - AUTO_KEEP_FRACTION
    shares = r"2 connected components \(their shares of the area: 80 % \(320 faces\), 20 %"
    with pytest.raises(ValueError, match=shares):
        ofp.eigenbasis(V2, F2, k=5)
    eig = ofp.eigenbasis(V2, F2, k=5, components="largest")
    ref = ofp.eigenbasis(V, F, k=5)
    np.testing.assert_allclose(eig.evals, ref.evals, rtol=1e-9)
    assert eig.cleaning.report.dropped_fraction == pytest.approx(0.2, rel=1e-9)


def test_check_shape_refuses_what_the_cleaning_refuses_without_a_laplacian(monkeypatch):
    """check_shape gives clean_shape's refusals (components, faces) and builds no Laplacian."""
    import o3d_ofp.core.cleaning as cleaning

    V, F = icosphere(2)
    small = 0.5 * V + [4.0, 0, 0]
    V2, F2 = np.concatenate([V, small]), np.concatenate([F, F + len(V)])
    messages = []
    for options in ({}, {"components": "error"}):
        with pytest.raises(ValueError) as full:
            clean_shape(V2, F2, **options)
        messages.append(str(full.value))
    monkeypatch.setattr(cleaning, "laplacian", lambda *a, **k: pytest.fail("Laplacian built"))
    for options, message in zip(({}, {"components": "error"}), messages, strict=True):
        with pytest.raises(ValueError) as cheap:
            check_shape(V2, F2, **options)
        assert str(cheap.value) == message and "2 connected components" in message
    with pytest.raises(ValueError, match="all 1 faces are degenerate"):
        check_shape(V, [[0, 0, 1]])
    check_shape(V2, F2, components="largest")  # accepted: nothing raised
    check_shape(V, F)
    check_shape(np.concatenate([V, V + 5.0]))  # a cloud's components are not checked here


def test_a_pair_is_checked_before_either_shape_is_solved(monkeypatch):
    """The second shape's components are refused before the first one's eigensolve."""
    import o3d_ofp.workflows.plan as eigenbases_module

    V, F = icosphere(3)
    V2 = np.concatenate([V, V + np.array([4.0, 0.0, 0.0])])
    F2 = np.concatenate([F, F + len(V)])
    solved = []
    real = eigenbases_module.eigenbasis
    monkeypatch.setattr(
        eigenbases_module, "eigenbasis", lambda *a, **k: solved.append(1) or real(*a, **k)
    )
    with pytest.raises(ValueError, match=r"^the target: the shape has 2 connected components"):
        ofp.match((V, F), (V2, F2), components="error")
    with pytest.raises(ValueError, match=r"^the target: the shape has 2 connected components"):
        ofp.match((V, F), (V2, F2))  # "auto": two equal pieces
    assert solved == []
    ofp.match((V, F), (V2, F2), components="largest")
    assert len(solved) == 2  # the same path, accepted: both solved


def test_non_manifold_edge_and_boundary_give_a_basis():
    V, F = icosphere(3)
    # Two fins glued on one edge of the sphere: three triangles share it (non-manifold).
    a, b = F[0, 0], F[0, 1]
    mid = 0.5 * (V[a] + V[b])
    fins_v = np.array([mid * 1.5, mid * 1.3 + 0.1])
    n = len(V)
    V2 = np.concatenate([V, fins_v])
    F2 = np.concatenate([F, [[a, b, n], [b, a, n + 1]]])
    eig = ofp.eigenbasis(V2, F2, k=12)
    assert eig.cleaning is None  # nothing to clean: kept as is
    _check_meaningful(eig, len(V2), 12)
    # An open surface (a hemisphere) gets Neumann conditions: the constant is an eigenfunction.
    keep = np.all(V[F][:, :, 2] > -0.05, axis=1)
    Fh = F[keep]
    used = np.unique(Fh)
    remap = np.full(n, -1)
    remap[used] = np.arange(used.shape[0])
    eig_h = ofp.eigenbasis(V[used], remap[Fh], k=12)
    _check_meaningful(eig_h, used.shape[0], 12)


def test_duplicated_vertices_give_the_same_transfer_on_the_original_vertices():
    V, F = blob(3)
    rng = np.random.default_rng(1)
    dup = rng.choice(len(V), 100, replace=False)
    Vd = np.concatenate([V, V[dup]])
    # Re-point a random half of the faces that use a duplicated vertex to its copy.
    copy_of = {int(v): len(V) + i for i, v in enumerate(dup)}
    Fd = F.copy()
    for row in range(len(F)):
        if rng.random() < 0.5:
            Fd[row] = [copy_of.get(int(v), int(v)) for v in F[row]]
    target = blob(3, seed=7)
    eig_t = ofp.eigenbasis(*target, k=12)
    eig_d = ofp.eigenbasis(Vd, Fd, k=12)
    eig_c = ofp.eigenbasis(V, F, k=12)
    f = np.sin(3 * V[:, 0]) + V[:, 1] ** 2
    f_d = np.concatenate([f, f[dup]])
    p2p = np.arange(len(target[0])) % len(V)  # any map, given on original indices
    kw = dict(options=ofp.BasisOptions(k1=12, k2=12, order=2))

    def given(p2p, eig_1, eig_2):
        return ofp.Correspondence.from_p2p(p2p, eig_1.n_vertices, eig_2.n_vertices)

    g_c = transfer_function(f, eig_c, eig_t, correspondence=given(p2p, eig_c, eig_t), **kw)
    g_d = transfer_function(f_d, eig_d, eig_t, correspondence=given(p2p, eig_d, eig_t), **kw)
    # Same bases up to round-off (the orthogonalization sees identical rows).
    np.testing.assert_allclose(g_d, g_c, atol=1e-9 * np.abs(g_c).max())
    # Duplicates on the target side: the output is on every original target vertex.
    Vt, Ft = target
    Vtd = np.concatenate([Vt, Vt[:50]])
    eig_td = ofp.eigenbasis(Vtd, Ft, k=12)  # 50 unreferenced copies: removed, then refilled
    p2p_d = np.arange(len(Vtd)) % len(V)
    g_td = transfer_function(f, eig_c, eig_td, correspondence=given(p2p_d, eig_c, eig_td), **kw)
    assert g_td.shape == (len(Vtd),)
    np.testing.assert_allclose(g_td[: len(Vt)], g_c, atol=1e-9 * np.abs(g_c).max())
    np.testing.assert_allclose(g_td[len(Vt) :], g_c[:50], atol=1e-9 * np.abs(g_c).max())


def test_point_clouds_duplicates_collinear_tiny():
    V, _ = icosphere(3)
    cloud = np.concatenate([V, V[:40]])  # duplicated scan points
    eig = ofp.eigenbasis(cloud, None, k=8)
    assert eig.cleaning.report.merged_vertices == 40
    _check_meaningful(eig, len(cloud), 8)
    np.testing.assert_allclose(eig.evecs[len(V) :], eig.evecs[:40])
    # Point-cloud Laplacian on a sphere: eigenvalues 2 (x3) and 6 (x5), 3 % as in test_spectrum.
    np.testing.assert_allclose(eig.evals[1:], np.repeat([2.0, 6.0], [3, 5]), rtol=3e-2)
    line = np.outer(np.linspace(0, 1, 50), [1.0, 2.0, 3.0])
    with pytest.raises(ValueError, match="collinear"):
        ofp.eigenbasis(line, None, k=3)
    with pytest.raises(ValueError, match="only 1 distinct points"):
        ofp.eigenbasis(np.ones((20, 3)), None, k=3)
    with pytest.raises(ValueError, match="at least 4 distinct points"):
        ofp.eigenbasis(np.eye(3), None, k=1)
    for n in (4, 6, 10):  # very small clouds: a basis or a clear error, never a crash
        pts = np.random.default_rng(n).standard_normal((n, 3))
        eig = ofp.eigenbasis(pts, None, k=n - 1)
        assert eig.evecs.shape == (n, n)
        assert np.abs(_mass_gram(eig) - np.eye(n)).max() < 1e-8


def test_ply_with_triangle_strips_or_only_points_uses_the_point_cloud_path(tmp_path):
    pytest.importorskip("open3d")
    from o3d_ofp import read_geometry

    V, F = icosphere(3)
    header = [
        "ply",
        "format ascii 1.0",
        f"element vertex {len(V)}",
        "property float x",
        "property float y",
        "property float z",
        "element tristrips 1",
        "property list int int vertex_indices",
        "end_header",
    ]
    strip = np.concatenate([np.append(f, -1) for f in F])  # one strip per triangle
    body = [" ".join(map(str, v)) for v in V] + [" ".join(map(str, [len(strip), *strip]))]
    path = tmp_path / "strips.ply"
    path.write_text("\n".join(header + body) + "\n")
    cloud = read_geometry(path)
    assert type(cloud).__name__ == "PointCloud"
    eig = ofp.eigenbasis(cloud, k=8)
    _check_meaningful(eig, len(V), 8)
    # The sphere's spectrum from the points alone (3 % as for every point-cloud Laplacian test).
    np.testing.assert_allclose(eig.evals[1:], np.repeat([2.0, 6.0], [3, 5]), rtol=3e-2)


def test_tiny_meshes_and_k_limits():
    tri = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0.2], [0.5, 1.8, 0.1]])
    for m, faces in enumerate(
        ([[0, 1, 2]], [[0, 1, 2], [1, 3, 2]], [[0, 1, 2], [1, 3, 2], [2, 3, 4]])
    ):
        F = np.array(faces)
        n = len(np.unique(F))
        eig = ofp.eigenbasis(tri[:n], F, k=n - 1)
        assert eig.evecs.shape == (n, n), m
        B = ofp.ofp_basis(eig)
        assert B.Q.shape[1] <= n
        with pytest.raises(ValueError, match=f"k={n} but the shape has {n} vertices"):
            ofp.eigenbasis(tri[:n], F, k=n)
        assert ofp.eigenbasis(tri[:n], F, k=50, clamp_k=True).k == n - 1


def test_memory_estimate_refuses_before_allocating(monkeypatch):
    V, F = blob(3)
    eig = ofp.eigenbasis(V, F, k=20)
    monkeypatch.setattr(_memory, "available_memory", lambda: 10_000_000)
    with pytest.raises(ValueError, match=r"product basis .* needs about .* more than the 10 MB"):
        ofp.ofp_basis(eig, order=3)
    with pytest.raises(ValueError, match=r"the eigensolver .* needs about"):
        ofp.eigenbasis(*blob(5), k=200)


def test_cleaning_survives_save_and_load(tmp_path):
    V, F = blob(3)
    Vs, Fs = _soup(V, F)
    B = ofp.ofp_basis(ofp.eigenbasis(Vs, Fs, k=8))
    B.save(tmp_path / "b.npz")
    B2 = ofp.OFPBasis.load(tmp_path / "b.npz")
    assert B2.eig.cleaning.report == B.eig.cleaning.report
    np.testing.assert_array_equal(B2.eig.cleaning.index, B.eig.cleaning.index)
    np.testing.assert_array_equal(B2.Q, B.Q)


NASTY = [
    "70-Crank-res9.off",
    "StanfordBunny_raw_scan.ply",
    "bun000_range_grid.ply",
    "bunny_poly.ply",
    "cuts_dog_shape_12.off",
    "dog.off",
    "hemisphere.obj",
    "teapot.obj",
]


def test_every_nasty_file_is_listed():
    if not (DATA / "nasty").is_dir():
        pytest.skip(f"research data not available: {DATA / 'nasty'}")
    assert sorted(p.name for p in (DATA / "nasty").iterdir()) == sorted(NASTY)


@pytest.mark.parametrize("name", NASTY)
def test_nasty_file_gives_a_basis_and_a_self_transfer_or_a_clear_error(name):
    path = shared_path(f"nasty/{name}")
    pytest.importorskip("open3d", reason="Open3D reads the nasty/ files")
    from o3d_ofp import read_geometry
    from o3d_ofp.boundary.convert import geometry_to_arrays

    V, F = geometry_to_arrays(read_geometry(path))
    V0 = V.copy()
    try:
        eig = ofp.eigenbasis(V, F, k=29, clamp_k=True)
    except ValueError as exc:
        # The only refusal among these files: the teapot (body, spout + handle, lid are
        # separate pieces, the largest holding 79 % of the area).
        assert name == "teapot.obj", exc
        assert "3 connected components" in str(exc) and "components='largest'" in str(exc)
        eig = ofp.eigenbasis(V, F, k=29, components="largest")
    np.testing.assert_array_equal(V, V0)
    k = eig.k
    B = ofp.ofp_basis(eig)
    assert B.Q.shape[0] == len(V)
    # More functions than eigenfunctions, unless the eigenbasis already spans every function
    # (the 27-vertex hemisphere, where k was clamped to n - 1).
    assert B.Q.shape[1] > k + 1 or B.Q.shape[1] == eig.n_vertices
    assert np.all(np.isfinite(B.Q))
    # Self-transfer with the identity map reproduces the basis approximation of the
    # coordinates on every input vertex.
    X = V - V.mean(axis=0)
    identity = ofp.Correspondence.from_p2p(np.arange(len(V)), len(V), len(V))
    g = transfer_function(X, eig, eig, correspondence=identity, bases=(B, B))
    np.testing.assert_allclose(g, B.approximate(X), atol=1e-9 * np.abs(X).max())
    assert B.approximation_error(X) < 0.2


def test_cleaning_maps_values_between_input_and_cleaned_vertices():
    V, F = icosphere(1)
    Vd = np.concatenate([V, V[:2]])  # input vertices 42, 43 duplicate 0, 1
    c = clean_shape(Vd, F).cleaning
    assert c.n_input == 44 and c.n_vertices == 42
    np.testing.assert_array_equal(c.multiplicity[:3], [2, 2, 1])
    g = np.arange(42.0)
    np.testing.assert_array_equal(c.extend(g), np.concatenate([g, [0.0, 1.0]]))
    f = np.arange(44.0)
    f[42], f[43] = 10.0, 20.0  # the duplicates disagree with their representatives
    r = c.restrict(f)
    np.testing.assert_allclose(r[:3], [(0 + 10) / 2, (1 + 20) / 2, 2.0])  # means
    np.testing.assert_allclose(c.restrict(np.column_stack([f, -f]))[:, 1], -r)
    with pytest.raises(ValueError, match="the cleaned shape has 42"):
        c.extend(np.zeros(5))


def test_the_cleaned_surface_basis_has_the_cleaned_faces():
    """on_cleaned_vertices gives the surface's triangles as clean_shape made them.

    The partial match reads its geodesic graph from them (the input's faces name only one
    copy of each welded vertex, so a soup's other copies are isolated there).
    """
    from o3d_ofp.core.spectrum import on_cleaned_vertices

    V, F = icosphere(2)
    stray = np.array([[3.0, 0, 0], [3.01, 0, 0], [3.0, 0.01, 0]])
    soup_V = np.concatenate([V[F.ravel()], stray])  # a soup, and a stray triangle dropped
    soup_F = np.concatenate([np.arange(F.size).reshape(-1, 3), [[F.size, F.size + 1, F.size + 2]]])
    soup_F = np.concatenate([soup_F, soup_F[:5]])  # five triangles given twice
    eig = ofp.eigenbasis(soup_V, soup_F, k=5)
    surface, rep = on_cleaned_vertices(eig)
    cleaned = clean_shape(soup_V, soup_F)
    np.testing.assert_array_equal(surface.faces, cleaned.faces)
    np.testing.assert_array_equal(surface.vertices, soup_V[rep])
    assert surface.faces.shape == F.shape and surface.n_vertices == len(V)
    # the same triangles as the welded sphere's, renumbered
    welded = {tuple(sorted(t)) for t in np.unique(np.sort(F, axis=1), axis=0)}
    where = {tuple(p): i for i, p in enumerate(V)}
    to_sphere = np.array([where[tuple(p)] for p in surface.vertices])
    assert {tuple(sorted(t)) for t in to_sphere[surface.faces]} == welded


def test_a_mesh_whose_faces_lie_on_a_line_is_refused():
    """Faces with distinct but collinear corners span no surface: refused, as such clouds are.

    (Their cotangent Laplacian still had eigenpairs, and every command wrote a result.) A mesh
    with only some faces of zero area (slivers) is still cleaned and solved.
    """
    from o3d_ofp.core.cleaning import check_shape

    line = np.outer(np.arange(6.0), [1.0, 2.0, 3.0])
    faces = np.array([[0, 1, 2], [1, 2, 3], [2, 3, 4], [3, 4, 5]])
    with pytest.raises(ValueError, match="the 4 faces have no area"):
        ofp.clean_shape(line, faces)
    with pytest.raises(ValueError, match="no area"):  # the cheap check before the eigensolves
        check_shape(line, faces)
    V, F = icosphere(2)
    sliver = np.vstack([V, (V[F[0, 0]] + V[F[0, 1]]) / 2])  # a zero-area face on an edge
    F2 = np.vstack([F, [[F[0, 0], len(V), F[0, 1]]]])
    assert ofp.clean_shape(sliver, F2).cleaning.report.faces == len(F2)
