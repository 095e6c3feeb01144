"""Bad input files: each refused at once, in one line naming the file and the cause.

A vertex with a NaN or inf coordinate, coordinates too far apart for float64's squares, a
face naming a vertex the file does not have: the message names the vertex or face as the file
numbers it (for OFF and OBJ with its line), whether Open3D read the file or not. A file named
.ply that is no PLY, or that Open3D's PLY reader (RPly, in C) stops reading, prints nothing:
what RPly writes to the process's stderr is quoted in the message instead.
"""

import os
import re

import numpy as np
import pytest

from o3d_ofp.boundary import convert as adapters
from o3d_ofp.core.shapes import icosphere

o3d = pytest.importorskip("open3d", reason="reading files needs Open3D")

from o3d_ofp import read_geometry  # noqa: E402

CUBE = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (0, 0, 1), (1, 0, 1), (1, 1, 1), (0, 1, 1)]
FACES = [(0, 1, 2), (0, 2, 3), (4, 5, 6), (4, 6, 7), (0, 1, 5), (0, 5, 4)]


def _vertices(value=None):
    """Return the cube's vertices as text lines, vertex 2's y replaced by ``value``."""
    rows = [[str(x) for x in v] for v in CUBE]
    if value is not None:
        rows[2][1] = value
    return [" ".join(r) for r in rows]


def _off(path, value=None, faces=FACES):
    lines = ["OFF", f"{len(CUBE)} {len(faces)} 0", *_vertices(value)]
    path.write_text("\n".join(lines + [f"3 {a} {b} {c}" for a, b, c in faces]) + "\n")
    return path


def _obj(path, value=None, faces=FACES):
    lines = [f"v {v}" for v in _vertices(value)]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in faces]
    path.write_text("\n".join(lines) + "\n")
    return path


def _ply(path, value=None, faces=FACES):
    header = ["ply", "format ascii 1.0", f"element vertex {len(CUBE)}"]
    header += [f"property float {a}" for a in "xyz"]
    header += [f"element face {len(faces)}", "property list uchar int vertex_indices"]
    lines = [*header, "end_header", *_vertices(value)]
    path.write_text("\n".join(lines + [f"3 {a} {b} {c}" for a, b, c in faces]) + "\n")
    return path


def _refused(path, message, capfd):
    """Read ``path``: a ValueError matching ``message``, one line, and nothing printed."""
    capfd.readouterr()
    with pytest.raises(ValueError, match=f"^{re.escape(str(path))}: {message}$") as info:
        read_geometry(path)
    assert "\n" not in str(info.value)
    assert capfd.readouterr() == ("", "")


MISSING = [*FACES[:3], (0, 1, 12), *FACES[4:]]  # face 3 names vertex 12 of 8


def test_well_formed_files_read(tmp_path):
    for write in (_off, _obj, _ply):
        mesh = read_geometry(write(tmp_path / f"cube.{write.__name__[1:]}"))
        assert len(mesh.vertices) == 8 and len(mesh.triangles) == 6


def test_a_face_naming_a_vertex_the_file_lacks(tmp_path, capfd):
    # line 1 OFF, line 2 the counts, lines 3-10 the vertices, face 3 on line 14
    _refused(
        _off(tmp_path / "x.off", faces=MISSING),
        r"face 3 \(line 14\) names vertex 12, but the file has 8 vertices \(0-based\)",
        capfd,
    )
    # OBJ numbers from 1: the fourth f line (line 12) names vertex 13
    _refused(
        _obj(tmp_path / "x.obj", faces=MISSING),
        r"face 4 \(line 12\) names vertex 13, but the file has 8 vertices \(1-based\)",
        capfd,
    )
    _refused(
        _ply(tmp_path / "x.ply", faces=MISSING),
        r"face 3 names vertex 12, but the file has 8 vertices \(0-based\)",
        capfd,
    )


def test_an_obj_face_counting_back_past_the_first_vertex(tmp_path, capfd):
    path = tmp_path / "back.obj"
    _obj(path)
    path.write_text(path.read_text() + "f 1 2 -9\n")
    _refused(
        path,
        r"face 7 \(line 15\) names vertex -9, but the file has 8 vertices \(1-based\)",
        capfd,
    )


@pytest.mark.parametrize(
    ("value", "cause"),
    [
        ("nan", "has a NaN coordinate"),
        ("inf", "has an infinite coordinate"),
        ("-inf", "has an infinite coordinate"),
    ],
)
def test_a_vertex_that_is_no_number(tmp_path, capfd, value, cause):
    # vertex 2 is on line 5 of the OFF (after its two header lines), line 3 of the OBJ
    _refused(_off(tmp_path / "x.off", value), rf"vertex 2 \(line 5\) {cause}", capfd)
    _refused(_obj(tmp_path / "x.obj", value), rf"vertex 3 \(line 3\) {cause}", capfd)
    if value == "nan":  # RPly reads "nan" (a float); it stops at "inf" (see below)
        _refused(_ply(tmp_path / "x.ply", value), rf"vertex 2 {cause}", capfd)


def test_coordinates_too_far_apart(tmp_path, capfd):
    span = (
        r"the vertices span 1e\+300 units: areas \(size²\) would overflow in float64; "
        r"rescale the coordinates \(the basis does not depend on the scale\)"
    )
    _refused(_off(tmp_path / "x.off", "1e300"), span, capfd)
    _refused(_obj(tmp_path / "x.obj", "1e300"), span, capfd)


def test_a_file_named_ply_that_is_no_ply_prints_nothing(tmp_path, capfd):
    for i, text in enumerate(["plx\nformat ascii 1.0\nend_header\n", "hello\n", "plyx\n"]):
        path = tmp_path / f"not{i}.ply"
        path.write_text(text)
        _refused(path, r"not a PLY file \(its first line is not 'ply'\)", capfd)


def test_what_rply_stops_at_is_quoted_not_printed(tmp_path, capfd):
    # 1e300 does not fit the "float" property: RPly stops at vertex 2
    _refused(
        _ply(tmp_path / "x.ply", "1e300"),
        r"Open3D's PLY reader stopped at \"Error reading 'y' of 'vertex' number 2\": the file "
        r"is damaged, cut short, or holds a value its property's type cannot hold",
        capfd,
    )
    # A binary PLY cut in its faces: the header's minimal size counts one byte per face.
    path = tmp_path / "whole.ply"
    o3d.io.write_triangle_mesh(str(path), adapters.triangle_mesh_from_arrays(*icosphere(2)))
    data = path.read_bytes()
    cut = tmp_path / "cut.ply"
    cut.write_bytes(data[: len(data) * 9 // 10])
    _refused(
        cut, r"Open3D's PLY reader stopped at \"Error reading .* of 'face' number \d+\".*", capfd
    )


def test_other_stderr_output_during_a_ply_read_is_passed_on(capfd):
    """What another thread writes to fd 2 while a PLY is read goes out, the RPly lines not."""
    from o3d_ofp.boundary.io import _reader_messages

    with _reader_messages() as said:
        os.write(2, b"RPly: Wrong magic number. Expected 'ply'\n")
        os.write(2, b"another thread's line\n")
    assert said == ["Wrong magic number. Expected 'ply'"]
    assert capfd.readouterr().err == "another thread's line\n"


def test_a_binary_mesh_with_one_nan_names_it(tmp_path):
    V, F = icosphere(3)
    V = V.copy()
    V[100] = np.nan
    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(V), o3d.utility.Vector3iVector(F))
    path = tmp_path / "big.ply"
    o3d.io.write_triangle_mesh(str(path), mesh)
    with pytest.raises(ValueError, match=r"big\.ply: vertex 100 has a NaN coordinate"):
        read_geometry(path)
