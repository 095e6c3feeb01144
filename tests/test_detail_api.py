"""``ofp.transfer_detail`` / ``ofp.filter_geometry`` and ``o3d-ofp detail`` / ``filter``."""

from __future__ import annotations

import re
import warnings

import numpy as np
import pytest
from numpy.polynomial import legendre

import o3d_ofp as ofp
from o3d_ofp.core.filtering import smooth_coordinates, smooth_gains
from o3d_ofp.core.geometry import vertex_normals
from o3d_ofp.core.shapes import blob, icosphere
from o3d_ofp.core.wording import OptionError
from tests.conftest import load_shared_mesh

o3d = pytest.importorskip("open3d", reason="Open3D-level functions and the command line")
from o3d_ofp.boundary.convert import (  # noqa: E402
    geometry_to_arrays,
    point_cloud_from_arrays,
    triangle_mesh_from_arrays,
)


def main(argv):
    """``o3d-ofp`` (imported here: a command line that does not import fails its tests only)."""
    from o3d_ofp.cli import main as cli_main

    return cli_main(argv)


def identity_map(source, target):
    """Return the identity vertex map between two shapes (geometries or (vertices, faces))."""
    n = len(geometry_to_arrays(target)[0]) if not isinstance(target, tuple) else len(target[0])
    return ofp.Correspondence.from_p2p(np.arange(n), source, target)


def _bumpy_sphere(level=3):
    """Return a unit sphere and the same sphere with known bumps (degree-10 and -9 harmonics)."""
    V, F = icosphere(level)
    n = V / np.linalg.norm(V, axis=1, keepdims=True)
    h = 0.03 * (legendre.legval(n[:, 2], [0] * 10 + [1]) + legendre.legval(n[:, 0], [0] * 9 + [1]))
    return n, (1 + h)[:, None] * n, h, F


@pytest.fixture(scope="module")
def spheres():
    smooth, bumpy, h, F = _bumpy_sphere(4)  # 2562 vertices
    return smooth, bumpy, h, F


def test_bumps_onto_the_smooth_sphere_open3d_level(spheres):
    smooth, bumpy, h, F = spheres
    source, target = triangle_mesh_from_arrays(bumpy, F), triangle_mesh_from_arrays(smooth, F)
    before = np.asarray(target.vertices).copy()
    identity = identity_map(source, target)
    # band 24: the whole degrees <= 4 of the sphere (its eigenvalues repeat 3, 5, 7, 9 times)
    out = ofp.transfer_detail(source, target, correspondence=identity, band=24)
    np.testing.assert_array_equal(np.asarray(target.vertices), before)  # input untouched
    X = np.asarray(out.vertices)
    # measured 0.072 (doing nothing: 1.0): the known bumps come back
    assert np.linalg.norm(X - bumpy, axis=1).mean() / np.abs(h).mean() < 0.1
    # the default (calibrated: the low-pass the smooth sphere fits best, at the source's
    # spread) on the same pair: measured 0.135, the bumps come back a little lower
    calibrated = ofp.transfer_detail(source, target, correspondence=identity).vertices
    assert np.linalg.norm(np.asarray(calibrated) - bumpy, axis=1).mean() / np.abs(h).mean() < 0.2


def test_detail_onto_itself_with_the_identity_returns_the_input(spheres):
    _, bumpy, _, F = spheres
    mesh = triangle_mesh_from_arrays(bumpy, F)
    out = ofp.transfer_detail(
        mesh, mesh, mode="replace-detail", correspondence=identity_map(mesh, mesh)
    )
    np.testing.assert_allclose(np.asarray(out.vertices), bumpy, atol=1e-10)


@pytest.fixture(scope="module")
def blob_pair():
    """Return a bumpy blob (source) and a smooth bent copy (target), same vertex order."""
    V, F = blob(3)  # 642 vertices
    n = vertex_normals(V, F)
    source = V + 0.02 * (np.sin(12 * V[:, 0]) * np.cos(10 * V[:, 1]))[:, None] * n
    target = V.copy()
    target[:, 1] += 0.15 * target[:, 0] ** 2
    return source, target, F


def _detail(source, target, F, **kw):
    kw.setdefault("correspondence", identity_map((source, F), (target, F)))
    out = ofp.transfer_detail((source, F), (target, F), band=20, **kw)
    return np.asarray(out.vertices)


def test_scale_and_permutation_invariance_open3d_level(blob_pair):
    source, target, F = blob_pair
    ref = _detail(source, target, F)
    assert np.abs(ref - target).max() > 1e-3  # the detail is there
    got = _detail(1e3 * source, 1e-2 * target, F)
    np.testing.assert_allclose(got / 1e-2, ref, atol=1e-7 * np.ptp(ref))
    rng = np.random.default_rng(1)
    perm = rng.permutation(len(target))  # new vertex i = old perm[i]
    inv = np.argsort(perm)
    permuted = ofp.Correspondence.from_p2p(perm, (source, F), (target[perm], inv[F]))
    got = ofp.transfer_detail(
        (source, F), (target[perm], inv[F]), band=20, correspondence=permuted
    )  # target vertex i (old perm[i]) comes from source vertex perm[i]
    np.testing.assert_allclose(np.asarray(got.vertices), ref[perm], atol=1e-8 * np.ptp(ref))


def test_coordinates_mode_and_its_deprecated_name(blob_pair):
    source, target, F = blob_pair
    identity = identity_map((source, F), (target, F))
    kw = dict(correspondence=identity, options=ofp.BasisOptions(k1=10, k2=10))
    X = np.asarray(ofp.transfer_detail((source, F), (target, F), mode="coordinates", **kw).vertices)
    # the paper's Fig. 13: the target takes the (approximated) source coordinates
    assert np.abs(X - source).max() < 0.05 * np.ptp(source)
    with pytest.warns(DeprecationWarning, match="'replace' is deprecated"):
        old = ofp.transfer_detail((source, F), (target, F), mode="replace", **kw)
    np.testing.assert_allclose(np.asarray(old.vertices), X)
    # k_low, the former name of band, is refused with its replacement named
    with pytest.raises(TypeError, match=r"no longer takes k_low=: use band="):
        ofp.transfer_detail((source, F), (target, F), k_low=20, correspondence=identity)


@pytest.fixture
def no_eigensolve(monkeypatch):
    """Make any eigensolve fail the test: the refusals must come before one."""
    from o3d_ofp.core import spectrum

    def refuse(*args, **kwargs):
        raise AssertionError("an eigensolve ran before the refusal")

    monkeypatch.setattr(spectrum, "_solve", refuse)


def test_transfer_detail_refuses_bad_options_before_any_eigensolve(blob_pair, no_eigensolve):
    source, target, F = blob_pair
    mesh_1, mesh_2 = triangle_mesh_from_arrays(source, F), triangle_mesh_from_arrays(target, F)
    identity = identity_map(mesh_1, mesh_2)
    # (keywords, exception, message, the option an OptionError names; None: Python's TypeError)
    cases = [
        ({"mode": "swap"}, ValueError, "mode must be one of 'add', 'replace-detail'", "mode"),
        ({"band": 0}, ValueError, "band must be >= 1", "band"),
        ({"band": 2.5}, TypeError, "band must be an integer", "band"),
        ({"band": True}, TypeError, "band must be an integer", "band"),
        ({"amount": -0.5}, ValueError, "amount must be a finite number in [0, 10]", "amount"),
        ({"amount": float("inf")}, ValueError, "amount must be a finite number in [0, 10]",
         "amount"),
        ({"amount": "1"}, TypeError, "amount must be a finite number in [0, 10]", "amount"),
        ({"bases": (np.eye(3), None)}, TypeError, "bases must be a pair (source, target)",
         "bases"),
        # the OFP bases' options given to a mode that builds none: refused, not ignored
        ({"options": ofp.BasisOptions(k2=29)}, ValueError,
         "options (the OFP bases' sizes and threshold) does not apply: mode 'add'", "options"),
        ({"mode": "replace-detail", "options": ofp.BasisOptions(order=3, preset="ours")},
         ValueError, "does not apply: mode 'replace-detail' carries the source's detail in "
         "local frames, with no OFP basis", "options"),
        # the former keywords are refused, each with what replaces it (k_low, the maps, components)
        ({"k_low": 0}, TypeError, "no longer takes k_low=: use band=", None),
        ({"components": "largest"}, TypeError,
         "no longer takes components=: use correspondence=o3d_ofp.match(source, target, "
         "components=...)", None),
    ]
    for mode in ("add", "replace-detail", "coordinates"):  # every mode: one way to give a map
        for old in ("p2p_21", "fmap_12", "eigenbases"):
            cases.append(({old: None, "mode": mode}, TypeError,
                          f"no longer takes {old}=: use ", None))  # fmt: skip
        cases.append(({"correspondence": np.arange(len(target)), "mode": mode}, TypeError,
                      "correspondence must be an o3d_ofp Correspondence", None))  # fmt: skip
    for kw, exc, message, option in cases:
        kw = {"correspondence": identity, **kw}
        with pytest.raises(exc, match=re.escape(message)) as info:
            ofp.transfer_detail(mesh_1, mesh_2, **kw)
        if option is not None:
            assert isinstance(info.value, OptionError) and info.value.option == option, kw
    np.testing.assert_array_equal(np.asarray(mesh_2.vertices), target)


def test_transfer_detail_computes_too_small_eigenbases_again(blob_pair):
    source, target, F = blob_pair
    small = ofp.eigenbasis(source, F, k=12), ofp.eigenbasis(target, F, k=12)
    identity = identity_map((source, F), (target, F))
    got = ofp.transfer_detail(
        (source, F), (target, F), band=20, bases=small, correspondence=identity
    )
    np.testing.assert_allclose(np.asarray(got.vertices), _detail(source, target, F), atol=1e-12)


def test_detail_onto_a_point_cloud_gets_estimated_normals(blob_pair):
    source, target, F = blob_pair
    cloud = point_cloud_from_arrays(target)
    assert not cloud.has_normals()
    mesh = triangle_mesh_from_arrays(source, F)
    out = ofp.transfer_detail(mesh, cloud, band=20, correspondence=identity_map(mesh, cloud))
    assert isinstance(out, o3d.geometry.PointCloud) and not cloud.has_normals()
    X = np.asarray(out.points)
    mesh_result = _detail(source, target, F)
    # the cloud's Laplacian is not the mesh's, but on this smooth target the rotations and
    # the scale barely depend on it: measured cosine 1 - 2e-8, norm ratio 0.996
    d_cloud, d_mesh = X - target, mesh_result - target
    cos = np.sum(d_cloud * d_mesh) / np.linalg.norm(d_cloud) / np.linalg.norm(d_mesh)
    assert cos > 0.99 and 0.95 < np.linalg.norm(d_cloud) / np.linalg.norm(d_mesh) < 1.05


# ---------------------------------------------------------------------------- filter_geometry


def _volume(V, F):
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def test_filter_geometry_smooth_is_the_volume_keeping_lowpass(spheres):
    smooth, _, _, F = spheres
    rng = np.random.default_rng(0)
    noisy = smooth * (1 + 0.01 * rng.standard_normal(len(smooth)))[:, None]
    mesh = triangle_mesh_from_arrays(noisy, F)
    # radius 0.03 √area = 0.11, above the edge length (0.08): the per-vertex noise goes
    out = np.asarray(ofp.filter_geometry(mesh, smooth=0.03).vertices)
    np.testing.assert_array_equal(np.asarray(mesh.vertices), noisy)  # input untouched
    eig = ofp.eigenbasis(noisy, F, k=1)
    np.testing.assert_allclose(out, smooth_coordinates(eig, noisy, smooth=0.03), atol=1e-12)
    # denoised (measured: mean radius error 0.0080 -> 0.0013) and the volume kept exactly
    r = np.linalg.norm(out, axis=1)
    assert np.abs(r - 1).mean() < 0.25 * np.abs(np.linalg.norm(noisy, axis=1) - 1).mean()
    assert _volume(out, F) == pytest.approx(_volume(noisy, F), rel=1e-9)
    # the same meaning at every scale: the result of the scaled input is the scaled result
    scaled = ofp.filter_geometry(triangle_mesh_from_arrays(7 * noisy, F), smooth=0.03)
    np.testing.assert_allclose(np.asarray(scaled.vertices), 7 * out, atol=1e-12)


def test_filter_geometry_sharpen_gains_and_refusals(blob_pair, monkeypatch):
    source, _, F = blob_pair
    mesh = triangle_mesh_from_arrays(source, F)
    sharp = np.asarray(ofp.filter_geometry(mesh, sharpen=1.0, smooth=0.02).vertices)
    # sharpening's low-pass has the cotangent weights (smoothing's the umbrella's)
    from o3d_ofp.core.filtering import lowpass

    low = lowpass(ofp.eigenbasis(source, F, k=3), source, smooth=0.02, weights="cotangent")
    # unsharp masking: the detail above the low-pass doubles (before the volume is restored)
    raw = np.asarray(
        ofp.filter_geometry(mesh, sharpen=1.0, smooth=0.02, keep_volume=False).vertices
    )
    np.testing.assert_allclose(raw - source, source - low, atol=1e-12)
    assert _volume(sharp, F) == pytest.approx(_volume(source, F), rel=1e-9)
    g = np.asarray(ofp.filter_geometry(mesh, gains=smooth_gains(5.0), k=10).vertices)
    assert g.shape == source.shape and not np.allclose(g, source)  # gains= still works
    from o3d_ofp.core import spectrum

    monkeypatch.setattr(spectrum, "_solve", lambda *a, **k: pytest.fail("eigensolve ran"))
    for kw, message in [
        ({}, "give smooth"),
        ({"smooth": 0.3}, "smooth must be in [0, 0.25]"),
        ({"smooth": -0.01}, "smooth must be in [0, 0.25]"),
        ({"sharpen": 2.5}, "sharpen must be in [0, 2]"),
        ({"sharpen": float("nan")}, "sharpen must be in [0, 2]"),
        ({"smooth": 0.01, "gains": [1.0]}, "give gains alone"),
    ]:
        with pytest.raises(ValueError, match=message.replace("[", r"\[").replace("]", r"\]")):
            ofp.filter_geometry(mesh, **kw)


# ---------------------------------------------------------------------------- command line


@pytest.fixture(scope="module")
def files(tmp_path_factory, blob_pair):
    from o3d_ofp import write_geometry

    source, target, F = blob_pair
    d = tmp_path_factory.mktemp("detail_cli")
    paths = {"src": str(d / "src.ply"), "tgt": str(d / "tgt.ply"), "cloud": str(d / "c.ply")}
    write_geometry(paths["src"], triangle_mesh_from_arrays(source, F))
    write_geometry(paths["tgt"], triangle_mesh_from_arrays(target, F))
    write_geometry(paths["cloud"], point_cloud_from_arrays(target))
    return paths


def test_cli_detail_modes(files, tmp_path, capsys):
    out = tmp_path / "d.ply"
    argv = ["detail", files["src"], files["tgt"], "--map", "identity", "--band", "20"]
    assert main([*argv, "-o", str(out)]) == 0
    X = np.asarray(o3d.io.read_triangle_mesh(str(out)).vertices)
    np.testing.assert_allclose(X, _detail(*_pair_arrays(files)), atol=1e-5)  # float32 file
    assert "band 20" in capsys.readouterr().out
    out_c = tmp_path / "c.ply"
    coords = ["detail", files["src"], files["tgt"], "--map", "identity", "--k1", "10"]
    assert main([*coords, "--k2", "10", "--mode", "coordinates", "-o", str(out_c)]) == 0
    out_r = tmp_path / "r.ply"
    assert main([*coords, "--k2", "10", "--mode", "replace", "-o", str(out_r)]) == 0
    assert "deprecated" in capsys.readouterr().err
    np.testing.assert_allclose(
        np.asarray(o3d.io.read_triangle_mesh(str(out_r)).vertices),
        np.asarray(o3d.io.read_triangle_mesh(str(out_c)).vertices),
    )
    out_p = tmp_path / "p.ply"
    cloud = ["detail", files["src"], files["cloud"], "--map", "identity", "--band", "20"]
    assert main([*cloud, "-o", str(out_p)]) == 0
    assert len(o3d.io.read_point_cloud(str(out_p)).points) == len(_pair_arrays(files)[1])


def _pair_arrays(files):
    from o3d_ofp import read_geometry
    from o3d_ofp.boundary.convert import geometry_to_arrays

    V1, F = geometry_to_arrays(read_geometry(files["src"]))
    V2, _ = geometry_to_arrays(read_geometry(files["tgt"]))
    return V1, V2, F


BAD = [
    (["detail", "{src}", "{tgt}", "--band", "0"], "expected a positive integer"),
    (["detail", "{src}", "{tgt}", "--band", "40", "--k1", "20"], "--k1 applies to --mode coord"),
    (["detail", "{src}", "{tgt}", "--k-low", "20", "--k2", "10"], "with no OFP basis: drop it"),
    (["detail", "{src}", "{tgt}", "--mode", "replace-detail", "--order", "3", "--preset", "ours"],
     "--order, --preset apply to --mode coordinates (the OFP bases); --mode replace-detail"),
    (["detail", "{src}", "{tgt}", "--k1", "40", "--k2", "40", "--tol", "0.1"],
     "--k1, --k2, --tol apply to --mode coordinates"),
    (["detail", "{src}", "{tgt}", "--k-low", "20", "--band", "25"], "--k-low 20 and --band 25"),
    (["detail", "{src}", "{tgt}", "--amount", "11"], "argument --amount"),
    (["detail", "{src}", "{tgt}", "--mode", "swap"], "argument --mode: invalid choice"),
    (["detail", "{src}", "{tgt}", "--mode", "coordinates", "--band", "20"], "--band does not"),
    (["detail", "{src}", "{tgt}", "--map", "identity", "--band", "700"], "--band (700): "),
    (["filter", "{src}"], "give --smooth RADIUS and/or --sharpen GAIN"),
    (["filter", "{src}", "--smooth", "5"], "argument --smooth: expected a number in [0, 0.25]"),
    (["filter", "{src}", "--sharpen", "2.5"], "argument --sharpen: expected a number in [0, 2]"),
    (["filter", "{src}", "--sharpen", "-1"], "argument --sharpen: expected a number in [0, 2]"),
]


@pytest.mark.parametrize(("argv", "message"), BAD)
def test_cli_refusals_exit_2_with_one_line(files, capsys, tmp_path, no_eigensolve, argv, message):
    argv = [a.format(**files) for a in argv] + ["-o", str(tmp_path / "x.ply")]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and message in err.strip().splitlines()[-1], err
    assert not list(tmp_path.iterdir())  # no output, no temporary file


def test_cli_filter_smooth_and_sharpen(files, tmp_path):
    V, _, F = _pair_arrays(files)
    out = tmp_path / "s.ply"
    assert main(["filter", files["src"], "--smooth", "0.02", "-o", str(out)]) == 0
    X = np.asarray(o3d.io.read_triangle_mesh(str(out)).vertices)
    ref = smooth_coordinates(ofp.eigenbasis(V, F, k=1), V, smooth=0.02)
    np.testing.assert_allclose(X, ref, atol=1e-5)  # float32 file
    out = tmp_path / "h.ply"
    assert main(["filter", files["src"], "--sharpen", "1", "--smooth", "0.02", "-o", str(out)]) == 0
    Y = np.asarray(o3d.io.read_triangle_mesh(str(out)).vertices)
    assert np.linalg.norm(Y - ref, axis=1).mean() > 1.5 * np.linalg.norm(V - ref, axis=1).mean()


def _two_spheres():
    """Return a mesh of two equal spheres (two components: components='auto' keeps neither)."""
    V, F = icosphere(2)
    shift = np.array([5.0, 0.0, 0.0])
    return np.vstack([V, V + shift]), np.vstack([F, F + len(V)])


def test_components_keyword_reaches_every_call_that_computes_a_basis(tmp_path):
    """The message for several components says components='largest': every call takes it.

    filter_geometry takes it; transfer_detail takes the policy through the map
    (``correspondence=o3d_ofp.match(..., components=...)``) or the eigenbases given as
    ``bases=``, and its former ``components=`` keyword is refused with that replacement named.
    """
    two = _two_spheres()
    n = len(two[0])
    mesh = triangle_mesh_from_arrays(*two)
    with pytest.raises(ValueError, match="components='largest'"):
        ofp.filter_geometry(mesh, smooth=0.01)
    out = ofp.filter_geometry(mesh, smooth=0.01, components="largest")
    assert np.asarray(out.vertices).shape == (n, 3)
    identity = identity_map(two, two)
    with pytest.raises(ValueError, match="components='largest'"):
        ofp.transfer_detail(two, two, correspondence=identity, band=5)
    with pytest.raises(TypeError, match=r"no longer takes components=: use correspondence="):
        ofp.transfer_detail(two, two, correspondence=identity, band=5, components="largest")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ofp.OFPWarning)  # "kept the largest of 2 components"
        eig = ofp.eigenbasis(*two, k=10, components="largest")  # the rotations' 10 at band 5
    moved = np.asarray(
        ofp.transfer_detail(two, two, correspondence=identity, band=5, bases=(eig, eig)).vertices
    )
    assert moved.shape == (n, 3) and np.all(np.isfinite(moved))


def test_transfer_detail_says_how_it_takes_the_components_policy():
    """The advice for several components must be one transfer_detail can follow."""
    two = _two_spheres()
    with pytest.raises(ValueError, match="components='largest'") as info:
        ofp.transfer_detail(two, two, correspondence=identity_map(two, two), band=5)
    said = str(info.value)
    assert "bases=" in said or "match(" in said, said


def test_a_too_small_eigenbasis_is_computed_again_with_its_components_policy():
    two = _two_spheres()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ofp.OFPWarning)
        small = ofp.eigenbasis(*two, k=5, components="largest")  # band 5 needs 10 (rotations)
        moved = ofp.transfer_detail(
            two, two, correspondence=identity_map(two, two), band=5, bases=(small, small)
        )
    assert np.asarray(moved.vertices).shape == two[0].shape


def test_a_basis_of_another_shape_with_the_same_vertex_count_is_said():
    """Eigenbases swapped, or a basis of another pose: an OFPWarning, not silence."""
    V1, F = load_shared_mesh("faust/tr_reg_093.ply")
    V2, _ = load_shared_mesh("faust/tr_reg_087.ply")
    e1, e2 = ofp.eigenbasis(V1, F, k=30), ofp.eigenbasis(V2, F, k=30)
    identity = identity_map((V1, F), (V2, F))
    with pytest.warns(ofp.OFPWarning, match="basis was computed on another shape"):
        ofp.filter_geometry(triangle_mesh_from_arrays(V1, F), smooth=0.01, basis=e2)
    with pytest.warns(ofp.OFPWarning, match="source eigenbasis was computed on another shape"):
        ofp.transfer_detail(
            (V1, F), (V2, F), mode="replace-detail", correspondence=identity, bases=(e2, e1)
        )

    with warnings.catch_warnings():
        warnings.simplefilter("error", ofp.OFPWarning)  # the right ones, moved and scaled: quiet
        ofp.filter_geometry(triangle_mesh_from_arrays(2.0 * V1 + 1.0, F), smooth=0.01, basis=e1)
        ofp.transfer_detail(
            (V1, F), (V2, F), mode="replace-detail", correspondence=identity, bases=(e1, e2)
        )


def test_coordinates_mode_computes_small_eigenbases_again():
    V1, F = load_shared_mesh("faust/tr_reg_093.ply")
    V2, _ = load_shared_mesh("faust/tr_reg_087.ply")
    small = (ofp.eigenbasis(V1, F, k=14), ofp.eigenbasis(V2, F, k=14))
    out = ofp.transfer_detail(
        (V1, F), (V2, F), mode="coordinates", correspondence=identity_map((V1, F), (V2, F)),
        bases=small,
    )  # fmt: skip
    moved = np.asarray(out.vertices)
    # the identity map between two poses: the source's coordinates come back, up to the
    # basis' approximation (measured 0.4 % of the diagonal with k1 = 29, k2 = 39)
    assert np.abs(moved - V1).max() < 0.05 * np.ptp(V1, axis=0).max()


def test_coordinates_from_a_wrong_map_are_said():
    """Mode "coordinates" through a wrong map: 6.5 times the source's area (measured), said.

    Said whether the eigenbases are computed here or given (``bases=``); the frames'
    workflow, which said it too, no longer has this mode (see test_detail.py).
    """
    V1, F = load_shared_mesh("faust/tr_reg_093.ply")
    V2, _ = load_shared_mesh("faust/tr_reg_087.ply")
    rng = np.random.default_rng(0)
    wrong = ofp.Correspondence.from_p2p(
        rng.integers(0, len(V1), len(V2)), (V1, F), (V2, F)
    )  # a map with no structure
    with pytest.warns(ofp.OFPWarning, match="times the source's area"):
        ofp.transfer_detail((V1, F), (V2, F), mode="coordinates", correspondence=wrong)
    eigs = ofp.eigenbasis(V1, F, k=39), ofp.eigenbasis(V2, F, k=39)
    with pytest.warns(ofp.OFPWarning, match="times the source's area"):  # given eigenbases too
        ofp.transfer_detail((V1, F), (V2, F), mode="coordinates", correspondence=wrong, bases=eigs)
    with warnings.catch_warnings():
        warnings.simplefilter("error", ofp.OFPWarning)  # the true map: 0.95, quiet
        ofp.transfer_detail(
            (V1, F), (V2, F), mode="coordinates", correspondence=identity_map((V1, F), (V2, F))
        )


def test_cli_detail_basis_files(files, tmp_path, capsys, monkeypatch):
    """Basis files: eigenfunctions only in add mode; one threshold for both sides' bases.

    A trial: --basis-1 in add mode made an OFP basis of the target it never used, and in
    coordinates mode an "ours" file met the command's default "ours*" on the other side.
    """
    from o3d_ofp.core import basis as basis_module

    b_ours = tmp_path / "ours.npz"
    assert main(["basis", files["src"], "-k", "40", "--preset", "ours", "-o", str(b_ours)]) == 0
    plain, with_file = tmp_path / "plain.ply", tmp_path / "file.ply"
    argv = ["detail", files["src"], files["tgt"], "--map", "identity"]
    assert main([*argv, "-o", str(plain)]) == 0
    made = []
    real = basis_module.ofp_basis
    monkeypatch.setattr(basis_module, "ofp_basis", lambda *a, **k: made.append(1) or real(*a, **k))
    assert main([*argv, "--basis-1", str(b_ours), "-o", str(with_file)]) == 0
    assert not made  # add mode reads eigenfunctions only: no OFP basis is made
    # The same detail: the file's eigenbasis holds 40 eigenfunctions, the one computed 30, the
    # same up to the solver's round-off (and the PLY files' float32).
    X, Y = (np.asarray(ofp.read_geometry(p).vertices) for p in (with_file, plain))
    np.testing.assert_allclose(X, Y, atol=1e-5 * np.ptp(Y))
    capsys.readouterr()
    coords = [*argv, "--mode", "coordinates", "--basis-1", str(b_ours), "--k2", "40"]
    out = tmp_path / "c.ply"
    assert main([*coords, "-o", str(out)]) == 2  # detail's default is ours*: refused, said how
    err = capsys.readouterr().err
    assert "threshold 0.01, but the target's basis would be made with 1e-09 (--preset ours*, " \
        "this command's default)" in err and "pass --preset ours" in err, err
    assert not out.exists() and not made
    assert main([*coords, "--preset", "ours", "-o", str(out)]) == 0


def test_cli_calibrated_detail_onto_a_target_in_other_units(files, tmp_path):
    """The calibrated detail (no --band) onto a target in millimetres, with --target-scale.

    The result is the same-units result, written in the target's own millimetres.
    """
    from o3d_ofp import write_geometry

    _, V2, F = _pair_arrays(files)
    mm = tmp_path / "mm.ply"
    write_geometry(str(mm), triangle_mesh_from_arrays(V2 * 1000.0, F))
    out, out_mm = tmp_path / "d.ply", tmp_path / "d_mm.ply"
    argv = ["detail", files["src"], files["tgt"], "--map", "identity"]
    assert main([*argv, "-o", str(out)]) == 0
    argv[2] = str(mm)
    assert main([*argv, "--target-scale", "0.001", "-o", str(out_mm)]) == 0
    X = np.asarray(o3d.io.read_triangle_mesh(str(out)).vertices)
    X_mm = np.asarray(o3d.io.read_triangle_mesh(str(out_mm)).vertices)
    assert not np.allclose(X, V2, atol=1e-4)  # the calibration added detail
    # float32 files: 1e-5 of the blob's unit extent, in millimetres 1e-2
    np.testing.assert_allclose(X_mm, 1000.0 * X, atol=1e-2)
