"""The CLI with map files and closest-point maps: what a reused map says, and refusals.

Found by a new-user trial: a reused --map MAP.npz saved suspect, or made for other shapes,
passed --strict; --save-map could overwrite the --map it read; a read-only output folder
failed after the work; a point-cloud source went through the bases with --map closest.
"""

from __future__ import annotations

import os

import numpy as np
import pytest

import o3d_ofp as ofp
from o3d_ofp.cli import main
from o3d_ofp.core.shapes import blob

o3d = pytest.importorskip("open3d", reason="the CLI reads and writes with Open3D")


def _turned(V: np.ndarray, degrees: float) -> np.ndarray:
    a = np.radians(degrees)
    R = np.array([[np.cos(a), 0.0, np.sin(a)], [0.0, 1.0, 0.0], [-np.sin(a), 0.0, np.cos(a)]])
    centre = 0.5 * (V.min(0) + V.max(0))
    return (V - centre) @ R.T + centre


@pytest.fixture(scope="module")
def shapes(tmp_path_factory):
    from o3d_ofp.boundary.convert import point_cloud_from_arrays, triangle_mesh_from_arrays

    d = tmp_path_factory.mktemp("maps")
    V, F = blob(3)
    colors = 0.5 + 0.5 * np.sin(3 * V)
    paths = {name: str(d / f"{name}.ply") for name in ("src", "same", "turned", "cloud")}
    ofp.write_geometry(paths["src"], triangle_mesh_from_arrays(V, F, colors=colors))
    ofp.write_geometry(paths["same"], triangle_mesh_from_arrays(V, F))
    ofp.write_geometry(paths["turned"], triangle_mesh_from_arrays(_turned(V, 6.0), F))
    ofp.write_geometry(paths["cloud"], point_cloud_from_arrays(V, colors=colors))
    return d, paths, V, F, colors


def _err(capsys) -> str:
    return capsys.readouterr().err


def _bent_copy(V: np.ndarray, F: np.ndarray, folder) -> str:
    """Write a bent copy of the shape (its vertex count, another shape); return its path."""
    from o3d_ofp.boundary.convert import triangle_mesh_from_arrays

    bent = V.copy()
    bent[:, 1] += 0.3 * bent[:, 0] ** 2
    path = str(folder / "other.ply")
    ofp.write_geometry(path, triangle_mesh_from_arrays(bent, F))
    return path


def test_a_map_saved_suspect_is_said_and_refused_under_strict(shapes, tmp_path, capsys):
    _d, p, *_ = shapes
    saved = str(tmp_path / "turned.npz")
    # the 6° turned copy without --align: suspect (the closest points slide), saved anyway
    argv = ["transfer", p["src"], p["turned"], "--map", "closest", "--save-map", saved]
    assert main([*argv, "-o", str(tmp_path / "a.ply")]) == 0
    assert os.path.exists(saved)
    capsys.readouterr()
    reuse = ["transfer", p["src"], p["turned"], "--map", saved]
    assert main([*reuse, "-o", str(tmp_path / "b.ply")]) == 0
    out = capsys.readouterr()
    assert f"when saved, --map {saved} had map quality SUSPECT" in out.out
    # the stored reasons are said once, as a warning (stdout has the summary line above)
    assert (out.out + out.err).count("was saved with a suspect quality") == 1
    assert "was saved with a suspect quality" in out.err
    assert main([*reuse, "--strict", "-o", str(tmp_path / "c.ply")]) == 3
    assert "was saved with a suspect quality" in _err(capsys)
    assert not os.path.exists(tmp_path / "c.ply")


def test_a_map_of_other_shapes_is_refused_under_strict(shapes, tmp_path, capsys):
    _d, p, V, F, _colors = shapes
    saved = str(tmp_path / "pair.npz")
    assert main(["transfer", p["src"], p["turned"], "--map", "closest", "--align",
                 "--save-map", saved, "-o", str(tmp_path / "a.ply")]) == 0  # fmt: skip
    capsys.readouterr()
    # the same vertex counts, other shapes: the target is the untouched copy, not the turned
    other = _bent_copy(V, F, tmp_path)
    argv = ["transfer", p["src"], other, "--map", saved, "--strict", "-o", str(tmp_path / "b.ply")]
    assert main(argv) == 3
    out = capsys.readouterr()
    assert "was made for another target" in out.err
    assert not os.path.exists(tmp_path / "b.ply")
    # the stored verdict is told as the one it had when saved, not as this use's (a trial read
    # "map quality ok" followed by the refusal as two verdicts)
    assert f"when saved, --map {saved} had map quality ok" in out.out


@pytest.mark.parametrize("given", ["identity", "npy"])
def test_an_identity_or_file_map_saved_remembers_its_shapes(shapes, tmp_path, capsys, given):
    """``--map identity`` and a map file saved with ``--save-map`` warn on other shapes too.

    (A trial: only estimated and closest-point maps recorded their shapes.)
    """
    _d, p, V, F, _colors = shapes
    spec = "identity"
    if given == "npy":
        spec = str(tmp_path / "map.npy")
        np.save(spec, np.arange(len(V)))
    saved = str(tmp_path / "saved.npz")
    assert main(["transfer", p["src"], p["same"], "--map", spec, "--save-map", saved,
                 "-o", str(tmp_path / "a.ply")]) == 0  # fmt: skip
    assert "made for another" not in _err(capsys)
    other = _bent_copy(V, F, tmp_path)
    argv = ["transfer", p["src"], other, "--map", saved, "--strict", "-o", str(tmp_path / "b.ply")]
    assert main(argv) == 3
    assert "was made for another target" in _err(capsys)


def test_save_map_may_not_replace_the_map_read(shapes, tmp_path, capsys):
    _d, p, *_ = shapes
    saved = str(tmp_path / "m.npz")
    assert main(["transfer", p["src"], p["same"], "--map", "closest", "--save-map", saved,
                 "-o", str(tmp_path / "a.ply")]) == 0  # fmt: skip
    before = os.stat(saved).st_mtime_ns
    capsys.readouterr()
    argv = ["transfer", p["src"], p["same"], "--map", saved, "--save-map", saved]
    assert main([*argv, "-o", str(tmp_path / "b.ply")]) == 2
    assert "is the --map file read" in _err(capsys)
    assert os.stat(saved).st_mtime_ns == before and not os.path.exists(tmp_path / "b.ply")


def test_map_file_messages(shapes, tmp_path, capsys):
    _d, p, *_ = shapes
    junk = tmp_path / "junk.npz"
    junk.write_text("not an archive")
    out = ["-o", str(tmp_path / "a.ply")]
    assert main(["transfer", p["src"], p["same"], "--map", str(junk), *out]) == 2
    err = _err(capsys)
    assert "not an .npz archive" in err and "pickle" not in err
    assert main(["transfer", p["src"], p["same"], "--map", "nope.npz", *out]) == 2
    assert "estimate|closest|identity" in _err(capsys)
    # a mesh given as the map (a trial: told of a codec error), and a binary file named .vts
    assert main(["transfer", p["src"], p["same"], "--map", p["same"], *out]) == 2
    assert "a mesh or point-cloud file, not a map" in _err(capsys)
    binary = tmp_path / "m.vts"
    binary.write_bytes(bytes(range(128, 256)))
    assert main(["transfer", p["src"], p["same"], "--map", str(binary), *out]) == 2
    err = _err(capsys)
    assert "not a .vts file" in err and "binary" in err and "codec" not in err
    assert not os.path.exists(tmp_path / "a.ply")


def test_read_only_output_folder_is_refused_before_the_work(shapes, tmp_path, capsys,
                                                           read_only_folder):  # fmt: skip
    _d, p, *_ = shapes
    folder = read_only_folder
    assert main(["transfer", p["src"], p["same"], "-o", str(folder / "a.ply")]) == 2
    assert "cannot be written" in _err(capsys)
    argv = ["transfer", p["src"], p["same"], "--save-map", str(folder / "m.npz")]
    assert main([*argv, "-o", str(tmp_path / "a.ply")]) == 2
    assert "--save-map" in _err(capsys) and not os.path.exists(tmp_path / "a.ply")


def test_a_folder_that_refuses_files_is_named_before_the_work(shapes, tmp_path, capsys,
                                                              monkeypatch):  # fmt: skip
    """A folder where no file can be made is refused before the work, by its flag.

    A trial's "-o /sys/x.ply" (as root: permission bits do not stop it, the file system does)
    failed after the work with exit 2, naming a temporary file.
    """
    import tempfile

    from o3d_ofp.cli import _common
    from o3d_ofp.core import _atomic

    _d, p, *_ = shapes
    real = tempfile.mkstemp
    refused = str(tmp_path / "refuses")
    os.mkdir(refused)

    def mkstemp(*args, dir=None, **kwargs):
        if dir is not None and os.path.abspath(dir) == refused:
            raise PermissionError(1, "Operation not permitted", os.path.join(dir, ".tmp"))
        return real(*args, dir=dir, **kwargs)

    monkeypatch.setattr(_common.tempfile, "mkstemp", mkstemp)
    out = os.path.join(refused, "a.ply")
    assert main(["transfer", p["src"], p["same"], "--map", "identity", "-o", out]) == 2
    err = _err(capsys)
    assert f"-o {out}: the folder {refused} cannot be written (Operation not permitted)" in err
    assert ".tmp" not in err and os.listdir(refused) == []
    # A file that cannot be made during the run (the folder's check passed) is named itself.
    with pytest.raises(PermissionError) as info, _atomic.atomic_path(out):
        pass
    assert info.value.filename == out


def test_cloud_source_with_the_closest_map_copies_the_colors(shapes, tmp_path, capsys):
    _d, p, V, F, colors = shapes
    out = tmp_path / "a.ply"
    assert main(["transfer", p["cloud"], p["same"], "--map", "closest", "-o", str(out)]) == 0
    assert "exact pull-back" in capsys.readouterr().out
    got = np.asarray(o3d.io.read_triangle_mesh(str(out)).vertex_colors)
    np.testing.assert_allclose(got, colors, atol=1 / 255)  # the same points: the same colors
    # and from Python: transfer_colors pulls back through a closest map of a cloud source
    corr = ofp.match(ofp.read_geometry(p["cloud"]), (V, F), method="closest")
    assert corr.barycentric_21 is None
    target = ofp.transfer_colors(ofp.read_geometry(p["cloud"]), ofp.read_geometry(p["same"]),
                                 correspondence=corr)  # fmt: skip
    np.testing.assert_allclose(np.asarray(target.vertex_colors), colors, atol=1 / 255)


def test_python_closest_map_refuses_landmarks(shapes):
    _d, _p, V, F, _ = shapes
    with pytest.raises(ValueError, match="landmarks applies to method='estimate'"):
        ofp.match((V, F), (V, F), method="closest", landmarks=[[0, 0]])


def test_closest_map_waits_for_the_signal_and_says_its_reasons_once(shapes, tmp_path, capsys):
    """A colorless source is refused before the closest map; a reason is said once.

    Found by a trial: ``--map closest`` with a colorless source computed the map before
    refusing the missing colors, and printed a suspect map's reason twice (log and report).
    """
    _d, p, _V, _F, _ = shapes
    out = tmp_path / "a.ply"
    assert main(["transfer", p["same"], p["src"], "--map", "closest", "-o", str(out)]) == 2
    err = _err(capsys)
    assert "has no vertex colors" in err and "closest points" not in err  # before the map
    assert main(["transfer", p["src"], p["turned"], "--map", "closest", "-o", str(out)]) == 0
    captured = capsys.readouterr()
    assert "map quality SUSPECT" in captured.out
    said = (captured.out + captured.err).count("slide along the surface")
    assert said == 1, captured  # the warning once, not again in the report
    assert "pass --align" in captured.err and "align=True" not in captured.err


def test_side_outputs_may_not_replace_inputs_outputs_or_cache_entries(shapes, tmp_path, capsys):
    """--save-landmarks / --save-map are refused where they would replace another file.

    Found by a trial: --save-landmarks replaced the --signal file (then failed reading it)
    or was replaced by -o; --save-map replaced a --basis-2 file or a cache entry.
    """
    _d, p, V, _F, _ = shapes
    signal = tmp_path / "s.npy"
    np.save(signal, np.arange(len(V), dtype=np.float64))
    before = signal.read_bytes()
    base = ["transfer", p["src"], p["same"], "--landmarks", "0:0,10:10,20:20"]
    cases = [
        ([*base, "--signal", str(signal), "--save-landmarks", str(signal),
          "-o", str(tmp_path / "a.npy")], "--save-landmarks", "an input of this command"),
        ([*base, "--signal", "xyz", "--save-landmarks", str(tmp_path / "b.ply"),
          "-o", str(tmp_path / "b.ply")], "--save-landmarks", "the -o output"),
        ([*base, "--save-landmarks", str(tmp_path / "m.npz"), "--save-map",
          str(tmp_path / "m.npz"), "-o", str(tmp_path / "c.ply")], "--save-landmarks",
         "the --save-map file"),
    ]  # fmt: skip
    assert main(["basis", p["same"], "-o", str(tmp_path / "b2.npz")]) == 0
    basis = (tmp_path / "b2.npz").read_bytes()
    cases.append((["transfer", p["src"], p["same"], "--map", "identity", "--basis-2",
                   str(tmp_path / "b2.npz"), "--save-map", str(tmp_path / "b2.npz"),
                   "-o", str(tmp_path / "d.ply")], "--save-map", "an input of this command"))
    cache = tmp_path / "cache"
    cache.mkdir()
    cases.append((["transfer", p["src"], p["same"], "--map", "identity", "--cache", str(cache),
                   "--save-map", str(cache / "x.npz"), "-o", str(tmp_path / "e.ply")],
                  "--save-map", "--cache folder"))  # fmt: skip
    capsys.readouterr()
    for argv, flag, what in cases:
        assert main(argv) == 2, argv
        err = _err(capsys)
        assert flag in err and what in err, (argv, err)
    assert signal.read_bytes() == before and (tmp_path / "b2.npz").read_bytes() == basis
    assert not [f for f in tmp_path.iterdir() if f.suffix in (".ply", ".txt")]  # no result
    assert list(cache.iterdir()) == []


def test_read_only_cache_folder_is_refused_before_the_work(shapes, tmp_path, capsys,
                                                          read_only_folder):  # fmt: skip
    """A read-only --cache folder is refused first, naming the flag.

    Found by a trial: --cache into a read-only folder failed after the eigensolve (exit 1
    for `basis`), naming a temporary file and not the flag.
    """
    _d, p, *_ = shapes
    folder = read_only_folder
    for cache in (folder, folder / "sub" / "deeper"):
        for argv in (["basis", p["src"]], ["approximate", p["src"], "-o", str(tmp_path / "a.ply")],
                     ["transfer", p["src"], p["same"], "-o", str(tmp_path / "t.ply")]):  # fmt: skip
            assert main([*argv, "--cache", str(cache)]) == 2, argv
            err = _err(capsys)
            assert f"--cache {cache}" in err and "cannot be written" in err, err
    assert list(folder.iterdir()) == [] and not (tmp_path / "a.ply").exists()


def test_closest_map_onto_a_target_in_other_units_names_and_takes_target_scale(
    shapes, tmp_path, capsys
):
    """A copy in millimetres: the reason names ``--target-scale``, which gives the exact colors.

    With the flag, the copy's colors are the source's on the copy's own coordinates.

    The library's advice is Open3D's ``target.scale(...)``, which the command line could not
    follow (a trial).
    """
    from o3d_ofp.boundary.convert import triangle_mesh_from_arrays

    _d, p, V, F, colors = shapes
    mm = tmp_path / "same_mm.ply"
    ofp.write_geometry(mm, triangle_mesh_from_arrays(1000 * V, F))
    out = tmp_path / "a.ply"
    argv = ["transfer", p["src"], str(mm), "--map", "closest", "-o", str(out)]
    assert main(argv) == 0  # a suspect map is written (no --strict), and said
    err = _err(capsys)
    assert "multiply the target's coordinates by 0.001 (millimetres to metres), e.g. " \
        "--target-scale 0.001, then match again" in err
    assert main([*argv, "--target-scale", "0.001", "--strict"]) == 0
    written = ofp.read_geometry(out)
    np.testing.assert_allclose(np.asarray(written.vertices), 1000 * V, rtol=1e-6)
    # PLY colors are 8-bit
    np.testing.assert_allclose(np.asarray(written.vertex_colors), colors, atol=1 / 255)
