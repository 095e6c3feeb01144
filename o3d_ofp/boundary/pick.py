"""Picking landmark pairs by hand in Open3D's vertex-selection window.

:func:`pick_landmarks` opens the source, then the target, in
``open3d.visualization.VisualizerWithEditing`` (shift + left click picks a vertex, shift +
right click undoes, Q closes the window) and pairs the vertices in the order they were picked.
The window needs a display; without one the function refuses before opening anything.
"""

from __future__ import annotations

import logging
import os
import socket
import sys
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from ..core._validation import check_int
from .convert import geometry_to_arrays, like_target, require_open3d, vertex_colors

__all__ = ["has_display", "pick_landmarks", "validate_picks"]

logger = logging.getLogger(__name__)

#: A picker shows one geometry with a title and returns the vertex indices picked, in order.
Picker = Callable[[Any, str], Sequence[int]]


#: Seconds to wait for a display server to accept a connection.
DISPLAY_TIMEOUT = 1.0


def _answers(family: int, address: Any) -> bool:
    """Whether a server accepts a stream connection at ``address`` within the timeout."""
    with socket.socket(family, socket.SOCK_STREAM) as s:
        s.settimeout(DISPLAY_TIMEOUT)
        try:
            s.connect(address)
        except OSError:
            return False
    return True


def _x11_answers(display: str) -> bool:
    """Whether the X server of ``DISPLAY`` (``[host]:N[.screen]``) accepts a connection.

    A set ``DISPLAY`` with no server behind it (an ssh session without forwarding, a stale
    variable) made Open3D fall back to an off-screen context and wait for a window no one can
    close (a new user's trial: killed after 120 s).
    """
    host, _, rest = display.rpartition(":")
    number = rest.split(".")[0]
    if not number.isdigit():
        return False
    if host in ("", "unix") or host.startswith("/"):  # a local socket (or its full path)
        path = display if host.startswith("/") else f"/tmp/.X11-unix/X{number}"
        if sys.platform.startswith("linux") and _answers(socket.AF_UNIX, "\0" + path):
            return True  # Linux's abstract socket, which Xorg and Xwayland also listen on
        return _answers(socket.AF_UNIX, path)
    return _answers(socket.AF_INET, (host, 6000 + int(number)))


def has_display() -> bool:
    """Tell whether a window can be opened: a display server that answers, or macOS/Windows.

    X11: the server of ``DISPLAY`` accepts a connection; Wayland: the socket of
    ``WAYLAND_DISPLAY`` (under ``XDG_RUNTIME_DIR`` unless absolute) does.
    """
    if sys.platform in ("darwin", "win32"):
        return True
    wayland = os.environ.get("WAYLAND_DISPLAY")
    if wayland:
        path = os.path.join(os.environ.get("XDG_RUNTIME_DIR", ""), wayland)
        if _answers(socket.AF_UNIX, path):
            return True
    display = os.environ.get("DISPLAY")
    return bool(display) and _x11_answers(display)


def _viewable(geometry: Any) -> Any:
    """Build a legacy geometry whose vertex i is vertex i of ``geometry_to_arrays``."""
    # (vertices, faces) give a new mesh with vertex normals, or a cloud when faces is None
    return like_target(geometry_to_arrays(geometry), colors=vertex_colors(geometry))


def _pick_in_window(geometry: Any, title: str) -> list[int]:
    """Show ``geometry`` in Open3D's editing window; return the vertices picked (in order)."""
    o3d = require_open3d()
    vis = o3d.visualization.VisualizerWithEditing()
    if not vis.create_window(window_name=title, width=1024, height=768):
        raise RuntimeError(f"Open3D could not open a window for {title!r}")
    try:
        vis.add_geometry(_viewable(geometry))
        vis.run()  # until the user closes the window (Q)
    finally:
        vis.destroy_window()
    return [int(i) for i in vis.get_picked_points()]


def validate_picks(
    picked_source: Sequence[int], picked_target: Sequence[int], n_source: int, n_target: int,
    *, count: int | None = None,
) -> np.ndarray:  # fmt: skip
    """Pair two lists of picked vertices, checked.

    Parameters
    ----------
    picked_source, picked_target : sequence of int
        Vertices picked on each shape, in order (the i-th of one is paired with the i-th of
        the other).
    n_source, n_target : int
        Vertex counts of the shapes.
    count : int, optional
        Number of pairs required.

    Returns
    -------
    (p, 2) ndarray of int64
        ``[source vertex, target vertex]`` rows.

    Raises
    ------
    ValueError
        If nothing was picked, the counts differ (or differ from ``count``), an index is out of
        range, or a vertex was picked twice on one shape.
    """
    a = np.asarray(list(picked_source), dtype=np.int64).reshape(-1)
    b = np.asarray(list(picked_target), dtype=np.int64).reshape(-1)
    if a.size == 0 or b.size == 0:
        side = "source" if a.size == 0 else "target"
        raise ValueError(f"no vertex was picked on the {side} (shift + left click picks a vertex)")
    if a.size != b.size:
        raise ValueError(
            f"picked {a.size} vertices on the source but {b.size} on the target; pick the same "
            "number, in the same order, on both"
        )
    if count is not None and a.size != count:
        raise ValueError(f"count={count} pairs were asked for; {a.size} were picked")
    for arr, n, side in ((a, n_source, "source"), (b, n_target, "target")):
        if arr.min() < 0 or arr.max() >= n:
            raise ValueError(f"picked {side} vertices must lie in [0, {n}); got {arr.tolist()}")
        values, counts = np.unique(arr, return_counts=True)
        if np.any(counts > 1):
            raise ValueError(
                f"{side} vertex {int(values[counts > 1][0])} was picked twice; each landmark "
                "is one vertex"
            )
    return np.stack([a, b], axis=1)


def pick_landmarks(
    source: Any, target: Any, *, count: int | None = None, picker: Picker | None = None
) -> np.ndarray:
    """Pick landmark pairs by hand: the source's window first, then the target's.

    Parameters
    ----------
    source, target : Open3D TriangleMesh or PointCloud (legacy or tensor)
        The shapes. Indices refer to their vertices, in the geometries' own order.
    count : int, optional
        Number of pairs required (default: any number >= 1, the same on both shapes).
    picker : callable, optional
        ``picker(geometry, title) -> vertex indices``: another way of picking (default: Open3D's
        ``VisualizerWithEditing`` window, which needs a display).

    Returns
    -------
    (p, 2) ndarray of int64
        ``[source vertex, target vertex]`` pairs, in the order picked; for
        ``match(..., landmarks=...)`` or a ``--landmarks`` file.

    Raises
    ------
    RuntimeError
        Without a display (and no ``picker``): nothing is opened.
    ValueError
        If the picks do not pair up (nothing picked on a shape, not as many on both or not
        ``count``, a vertex picked twice on one shape) or ``count`` < 1.
    """
    if count is not None:
        count = check_int(count, name="count", minimum=1)
    n_source = geometry_to_arrays(source)[0].shape[0]
    n_target = geometry_to_arrays(target)[0].shape[0]
    if picker is None:
        if not has_display():
            raise RuntimeError(
                "picking landmarks needs a display (no X11 or Wayland server answers: DISPLAY "
                "and WAYLAND_DISPLAY are not set, or nothing listens there); "
                "give the landmark pairs as an array or a file instead"
            )
        picker = _pick_in_window
    how = f"{count} vertices" if count is not None else "vertices"
    logger.info("pick %s on the source (shift + left click; Q closes the window)", how)
    picked_source = picker(source, f"source: pick {how}, then press Q")
    logger.info("pick the matching vertices on the target, in the same order")
    picked_target = picker(
        target, f"target: pick the {len(picked_source)} matching vertices in order, then Q"
    )
    pairs = validate_picks(picked_source, picked_target, n_source, n_target, count=count)
    logger.info("picked %d landmark pairs", pairs.shape[0])
    return pairs
