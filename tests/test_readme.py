"""The README's Python example runs as written (on a generated colored mesh)."""

import re
from pathlib import Path

import numpy as np
import pytest

from o3d_ofp.core.shapes import blob

o3d = pytest.importorskip("open3d", reason="the README example uses Open3D")

README = Path(__file__).resolve().parents[1] / "README.md"


def test_readme_python_example(tmp_path, monkeypatch, capsys):
    code = re.findall(r"```python\n(.*?)```", README.read_text(), flags=re.S)[0]
    V, F = blob(3)
    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(V), o3d.utility.Vector3iVector(F))
    mesh.vertex_colors = o3d.utility.Vector3dVector(0.5 + 0.5 * np.sin(3 * V))
    o3d.io.write_triangle_mesh(str(tmp_path / "bunny.ply"), mesh)
    monkeypatch.chdir(tmp_path)
    exec(compile(code, "README.md", "exec"), {})
    assert "functions, error" in capsys.readouterr().out
    assert len(o3d.io.read_triangle_mesh("approx.ply").vertices) == len(V)
