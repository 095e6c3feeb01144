import os

import pytest

from o3d_ofp.cli import main

pytest.importorskip("open3d", reason="the demo writes meshes with Open3D")


def test_demo_writes_meshes_and_prints_errors(tmp_path, capsys):
    out = tmp_path / "demo"
    assert main(["demo", "-o", str(out), "--subdivisions", "3", "-k", "12"]) == 0
    text = capsys.readouterr().out
    assert "K eigs" in text and "ours*" in text and "RGB error" in text
    names = sorted(p.name for p in out.iterdir())
    assert names == ["blob_eigs.ply", "blob_original.ply", "blob_ours.ply", "blob_ours_star.ply"]
    import open3d as o3d

    mesh = o3d.io.read_triangle_mesh(str(out / "blob_ours.ply"))
    assert len(mesh.vertices) == 642 and mesh.has_vertex_colors()
    assert oct(os.stat(out / "blob_ours.ply").st_mode & 0o777) != "0o600"


def test_bad_usage_exit_codes(tmp_path, capsys):
    assert main(["nope"]) == 2
    assert main(["demo", "-k", "many"]) == 2
    assert main(["demo", "-o", str(tmp_path), "-k", "0", "--subdivisions", "2"]) == 2
    assert "k must be >= 1" in capsys.readouterr().err
