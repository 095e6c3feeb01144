"""Every Python block of the README runs as written (on generated colored meshes)."""

import re
from pathlib import Path

import numpy as np
import pytest

from o3d_ofp.core.shapes import blob

o3d = pytest.importorskip("open3d", reason="the README examples use Open3D")

README = Path(__file__).resolve().parents[1] / "README.md"
BLOCKS = re.findall(r"```python\n(.*?)```", README.read_text(), flags=re.S)


@pytest.fixture
def files(tmp_path, monkeypatch):
    """Write the files the README's examples read: a colored blob and a bent copy."""
    V, F = blob(3)
    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(V), o3d.utility.Vector3iVector(F))
    mesh.vertex_colors = o3d.utility.Vector3dVector(0.5 + 0.5 * np.sin(3 * V))
    for name in ("bunny.ply", "source.ply"):
        o3d.io.write_triangle_mesh(str(tmp_path / name), mesh)
    bent = V.copy()
    bent[:, 1] += 0.15 * bent[:, 0] ** 2
    target = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(bent), o3d.utility.Vector3iVector(F)
    )
    o3d.io.write_triangle_mesh(str(tmp_path / "target.ply"), target)
    monkeypatch.chdir(tmp_path)
    return tmp_path, len(V)


def test_readme_has_python_blocks():
    assert len(BLOCKS) >= 2


@pytest.mark.parametrize("index", range(len(BLOCKS)))
def test_readme_python_block(index, files, capsys):
    tmp_path, n = files
    namespace: dict = {}
    exec(compile(BLOCKS[index], f"README.md, Python block {index + 1}", "exec"), namespace)
    out = capsys.readouterr().out
    if "ofp.match(" in BLOCKS[index]:
        assert "map quality ok" in out
        colored = o3d.io.read_triangle_mesh("colored.ply")
        assert len(colored.vertices) == n and colored.has_vertex_colors()
        assert (tmp_path / "map.npz").exists()
    if "approximation_error" in BLOCKS[index]:
        assert "functions, error" in out
        # The printed error is the colors' relative error in the order-2 basis: well below 1.
        assert float(out.split("error")[-1]) < 0.5
    if "filter_geometry" in BLOCKS[index]:
        assert len(namespace["smooth"].vertices) == n
