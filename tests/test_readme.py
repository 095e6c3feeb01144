"""The README's Python example runs as written (on a generated colored mesh)."""

import re
from pathlib import Path

import numpy as np
import pytest

from o3d_ofp.core.shapes import blob

o3d = pytest.importorskip("open3d", reason="the README example uses Open3D")

README = Path(__file__).resolve().parents[1] / "README.md"


def test_readme_python_examples(tmp_path, monkeypatch, capsys):
    blocks = re.findall(r"```python\n(.*?)```", README.read_text(), flags=re.S)
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
    # The first block: match and transfer in one call each.
    exec(compile(blocks[0], "README.md", "exec"), {})
    assert "map quality ok" in capsys.readouterr().out
    colored = o3d.io.read_triangle_mesh("colored.ply")
    assert len(colored.vertices) == len(V) and colored.has_vertex_colors()
    assert (tmp_path / "map.npz").exists()
    # The second: the basis step by step.
    exec(compile(blocks[1], "README.md", "exec"), {})
    assert "functions, error" in capsys.readouterr().out
    assert len(o3d.io.read_triangle_mesh("approx.ply").vertices) == len(V)
