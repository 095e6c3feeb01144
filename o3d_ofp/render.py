"""Headless pictures: lit renders of meshes and point clouds, side by side, with titles.

Rendering uses Open3D's legacy ``Visualizer`` with a hidden window, which runs over EGL
(Mesa) without a display, in a **separate interpreter** (``python -m o3d_ofp._render_worker``,
arrays exchanged through a temporary ``.npz``): when no OpenGL context can be created,
``create_window`` returns False and the next call would crash the interpreter, so a crash
or a hang there must not take the caller down. ``open3d.visualization.rendering.
OffscreenRenderer`` is not used (in Open3D 0.20 its Vulkan/Filament backend aborts or hangs on
a CPU-only machine), nor ``draw_geometries`` without a display (it blocks forever).

The panel (tiles, titles, color bar) is composed with NumPy and written as a PNG by a small
encoder here (no imaging library needed), atomically.
"""

from __future__ import annotations

import dataclasses
import logging
import os
import struct
import subprocess
import sys
import tempfile
import zlib
from collections.abc import Sequence
from typing import Any

import numpy as np

from ._atomic import atomic_path
from ._validation import as_faces, as_signal, as_vertices

__all__ = [
    "COLORMAPS",
    "RenderError",
    "View",
    "colormap",
    "read_png",
    "render_images",
    "render_panel",
    "show",
    "write_png",
]

logger = logging.getLogger(__name__)


class RenderError(RuntimeError):
    """No picture could be rendered (no OpenGL/EGL context, or the renderer crashed)."""


# Colormaps as anchors interpolated linearly (9 samples of matplotlib's "viridis", 3 of a
# diverging blue-grey-red map like "coolwarm"); plenty for a picture of a scalar field.
COLORMAPS: dict[str, np.ndarray] = {
    "viridis": np.array(
        [
            [0.267, 0.005, 0.329],
            [0.283, 0.141, 0.458],
            [0.254, 0.265, 0.530],
            [0.207, 0.372, 0.553],
            [0.164, 0.471, 0.558],
            [0.128, 0.567, 0.551],
            [0.135, 0.659, 0.518],
            [0.267, 0.749, 0.441],
            [0.993, 0.906, 0.144],
        ]
    ),
    "coolwarm": np.array([[0.230, 0.299, 0.754], [0.865, 0.865, 0.865], [0.706, 0.016, 0.150]]),
}


def colormap(
    values: Any,
    name: str = "viridis",
    *,
    vmin: float | None = None,
    vmax: float | None = None,
) -> np.ndarray:
    """Map scalar values to RGB colors.

    Parameters
    ----------
    values : (n,) array_like of float
        Scalars.
    name : {"viridis", "coolwarm"}, default "viridis"
        Colormap.
    vmin, vmax : float, optional
        Range mapped to the ends of the map (default: the values' min and max).

    Returns
    -------
    (n, 3) ndarray of float64
        Colors in [0, 1].
    """
    if name not in COLORMAPS:
        raise ValueError(f"colormap must be one of {sorted(COLORMAPS)}; got {name!r}")
    v = as_signal(values, np.shape(values)[0] if np.ndim(values) else 0, name="values")
    if v.ndim != 1:
        raise ValueError(f"values must be one scalar per vertex, shape (n,); got {v.shape}")
    lo = float(v.min()) if vmin is None else float(vmin)
    hi = float(v.max()) if vmax is None else float(vmax)
    t = np.clip((v - lo) / (hi - lo), 0.0, 1.0) if hi > lo else np.full(v.shape, 0.5)
    anchors = COLORMAPS[name]
    x = np.linspace(0.0, 1.0, anchors.shape[0])
    return np.stack([np.interp(t, x, anchors[:, c]) for c in range(3)], axis=1)


@dataclasses.dataclass(frozen=True)
class View:
    """Camera direction for a render: the shape is seen from ``front``, ``up`` pointing up.

    Attributes
    ----------
    front : (3,) tuple of float
        Direction from the shape's centre towards the camera.
    up : (3,) tuple of float
        Up direction on screen.
    zoom : float
        Open3D's zoom (smaller is closer); 0.6 fits a shape's bounding box with a margin.
    """

    front: tuple[float, float, float] = (0.0, 0.0, 1.0)
    up: tuple[float, float, float] = (0.0, 1.0, 0.0)
    zoom: float = 0.6


def _item(vertices: Any, faces: Any, colors: Any) -> dict[str, Any]:
    V = as_vertices(vertices)
    F = None if faces is None else as_faces(faces, V.shape[0])
    if colors is None:
        C = np.full((V.shape[0], 3), 0.7)
    else:
        C = as_signal(colors, V.shape[0], name="colors")
        if C.ndim == 1:
            C = colormap(C)
        if C.shape[1] != 3:
            raise ValueError(f"colors must have shape (n, 3) or (n,); got {C.shape}")
        C = np.clip(C, 0.0, 1.0)
    return {"vertices": V, "faces": F, "colors": C}


def render_images(
    items: Sequence[tuple[Any, Any, Any]],
    *,
    width: int = 480,
    height: int = 480,
    view: View | None = None,
    timeout: float = 300.0,
) -> list[np.ndarray]:
    """Render meshes or point clouds, one image each, in a child process.

    Parameters
    ----------
    items : sequence of (vertices, faces, colors)
        ``vertices`` (n, 3); ``faces`` (m, 3) or ``None`` for points; ``colors`` (n, 3) RGB
        in [0, 1], (n,) scalars (mapped with "viridis"), or ``None`` (grey).
    width, height : int, default 480
        Image size in pixels.
    view : View, optional
        Camera direction (default: looking along −z with y up).
    timeout : float, default 300
        Seconds before the renderer is considered hung and killed.

    Returns
    -------
    list of (height, width, 3) ndarray of uint8
        One lit render per item, white background.

    Raises
    ------
    RenderError
        When no OpenGL context can be created (no EGL library, no display) or the renderer
        crashes or hangs.
    """
    if not items:
        raise ValueError("items is empty: nothing to render")
    payload = [_item(*it) for it in items]
    for name, value in (("width", width), ("height", height)):
        if isinstance(value, bool) or not isinstance(value, int) or not 16 <= value <= 8192:
            raise ValueError(f"{name} must be an integer in [16, 8192]; got {value!r}")
    view = view or View()
    with tempfile.TemporaryDirectory(prefix="o3d_ofp_render.") as tmp:
        inp, out = os.path.join(tmp, "in.npz"), os.path.join(tmp, "out.npz")
        arrays: dict[str, Any] = {
            "count": np.int64(len(payload)),
            "width": np.int64(width),
            "height": np.int64(height),
            "front": np.array(view.front, dtype=np.float64),
            "up": np.array(view.up, dtype=np.float64),
            "zoom": np.float64(view.zoom),
        }
        for i, item in enumerate(payload):
            arrays[f"v{i}"], arrays[f"c{i}"] = item["vertices"], item["colors"]
            if item["faces"] is not None:
                arrays[f"f{i}"] = item["faces"]
        np.savez(inp, **arrays)
        try:
            proc = subprocess.run(
                [sys.executable, "-m", "o3d_ofp._render_worker", inp, out],
                stdin=subprocess.DEVNULL,
                stdout=subprocess.DEVNULL,  # Open3D's and EGL's console chatter
                stderr=subprocess.PIPE,
                timeout=timeout,
                check=False,
            )
        except subprocess.TimeoutExpired:
            raise RenderError(f"the renderer did not answer within {timeout:g} s") from None
        if proc.returncode == 3:
            raise RenderError(
                "no OpenGL context: create_window failed (on Debian: apt-get install libgl1 "
                "libegl1)"
            )
        if proc.returncode != 0 or not os.path.isfile(out):
            tail = proc.stderr.decode(errors="replace").strip().splitlines()[-1:]
            raise RenderError(
                f"the renderer process failed (exit status {proc.returncode})"
                + (f": {tail[0]}" if tail else "")
            )
        with np.load(out, allow_pickle=False) as images:
            return [images[f"img{i}"] for i in range(len(payload))]


# A 5×7 bitmap font (upper case, digits, punctuation) for titles and color-bar labels, so that
# no imaging library is needed. Each glyph: 7 rows of 5 pixels.
_FONT_ROWS = {
    "A": ".###.#...##...#######...##...##...#",
    "B": "####.#...##...#####.#...##...#####.",
    "C": ".###.#...##....#....#....#...#.###.",
    "D": "####.#...##...##...##...##...#####.",
    "E": "######....#....####.#....#....#####",
    "F": "######....#....####.#....#....#....",
    "G": ".###.#...##....#.####...##...#.####",
    "H": "#...##...##...#######...##...##...#",
    "I": ".###...#....#....#....#....#...###.",
    "J": "..###...#....#....#....#.#..#..##..",
    "K": "#...##..#.#.#..##...#.#..#..#.#...#",
    "L": "#....#....#....#....#....#....#####",
    "M": "#...###.###.#.##...##...##...##...#",
    "N": "#...##...###..##.#.##..###...##...#",
    "O": ".###.#...##...##...##...##...#.###.",
    "P": "####.#...##...#####.#....#....#....",
    "Q": ".###.#...##...##...##.#.##..#..##.#",
    "R": "####.#...##...#####.#.#..#..#.#...#",
    "S": ".#####....#.....###.....#....#####.",
    "T": "#####..#....#....#....#....#....#..",
    "U": "#...##...##...##...##...##...#.###.",
    "V": "#...##...##...##...##...#.#.#...#..",
    "W": "#...##...##...##.#.##.#.##.#.#.#.#.",
    "X": "#...##...#.#.#...#...#.#.#...##...#",
    "Y": "#...##...#.#.#...#....#....#....#..",
    "Z": "#####....#...#...#...#...#....#####",
    "0": ".###.#...##..###.#.###..##...#.###.",
    "1": "..#...##....#....#....#....#...###.",
    "2": ".###.#...#....#...#...#...#...#####",
    "3": "#####...#...#.....#.....##...#.###.",
    "4": "...#...##..#.#.#..#.#####...#....#.",
    "5": "######....####.....#....##...#.###.",
    "6": "..##..#...#....####.#...##...#.###.",
    "7": "#####....#...#...#...#....#....#...",
    "8": ".###.#...##...#.###.#...##...#.###.",
    "9": ".###.#...##...#.####....#...#..##..",
    " ": "...................................",
    ".": ".........................##...##...",
    ",": "....................##...#...#.....",
    ":": "......##...##........##...##.......",
    "-": "...............#####...............",
    "+": ".......#....#..#####..#....#.......",
    "=": "..........#####.....#####..........",
    "*": ".......#..#.#.#.###.#.#.#..#.......",
    "/": ".....#...#...#...#...#.............",
    "(": "...#...#...#....#....#.....#.....#.",
    ")": ".#.....#.....#....#....#...#...#...",
    "%": "##...##..#...#...#...#...#..##...##",
    "_": "..............................#####",
    "'": ".##...#...#........................",
    "!": "..#....#....#....#....#.........#..",
    "?": ".###.#...#....#...#...#.........#..",
    "#": ".#.#..#.#.#####.#.#.#####.#.#..#.#.",
    "<": "...#...#...#...#.....#.....#.....#.",
    ">": ".#.....#.....#.....#...#...#...#...",
    "[": ".###..#....#....#....#....#....###.",
    "]": ".###....#....#....#....#....#..###.",
    "×": "......#...#.#.#...#...#.#.#...#....",
}


def _glyph(ch: str) -> np.ndarray:
    rows = _FONT_ROWS.get(ch.upper(), _FONT_ROWS["?"])
    bits = np.array([c == "#" for c in rows.ljust(35, ".")[:35]], dtype=bool)
    return bits.reshape(7, 5)


def _draw_text(img: np.ndarray, text: str, x: int, y: int, scale: int, color=(0, 0, 0)) -> None:
    """Draw ``text`` in place with its top-left corner at (x, y), clipped to the image."""
    for i, ch in enumerate(text):
        g = np.kron(_glyph(ch), np.ones((scale, scale), dtype=bool))
        x0 = x + i * 6 * scale
        h = max(0, min(g.shape[0], img.shape[0] - y))
        w = max(0, min(g.shape[1], img.shape[1] - x0))
        if h == 0 or w == 0 or x0 < 0 or y < 0:
            continue
        region = img[y : y + h, x0 : x0 + w]
        region[g[:h, :w]] = color


def _text_width(text: str, scale: int) -> int:
    return len(text) * 6 * scale - scale


def _fit_scale(text: str, width: int, preferred: int) -> int:
    scale = preferred
    while scale > 1 and _text_width(text, scale) > width - 8:
        scale -= 1
    return scale


def _color_bar(width: int, name: str, vmin: float, vmax: float, scale: int) -> np.ndarray:
    bar_h, pad = 14 * scale // 2 + 6, 6
    strip = np.full((bar_h + 8 * scale + 3 * pad, width, 3), 255, dtype=np.uint8)
    x0, x1 = width // 8, width - width // 8
    ramp = colormap(np.linspace(0.0, 1.0, x1 - x0), name, vmin=0.0, vmax=1.0)
    strip[pad : pad + bar_h, x0:x1] = (ramp[None, :, :] * 255 + 0.5).astype(np.uint8)
    lo, hi = f"{vmin:.3g}", f"{vmax:.3g}"
    y = pad + bar_h + pad
    _draw_text(strip, lo, x0, y, scale)
    _draw_text(strip, hi, x1 - _text_width(hi, scale), y, scale)
    return strip


def render_panel(
    items: Sequence[tuple[Any, Any, Any]],
    path: str | os.PathLike[str] | None = None,
    *,
    titles: Sequence[str] | None = None,
    width: int = 400,
    height: int = 400,
    columns: int | None = None,
    view: View | None = None,
    scalar_range: tuple[float, float] | None = None,
    cmap: str = "viridis",
) -> np.ndarray:
    """Render several shapes side by side with titles (like the paper's figures).

    Parameters
    ----------
    items : sequence of (vertices, faces, colors)
        As in :func:`render_images`. Scalar ``colors`` share one color scale across the panel
        (``scalar_range``, default the min and max over all scalar items) and add a color bar.
    path : str or os.PathLike, optional
        Where to write the panel as a PNG (atomically).
    titles : sequence of str, optional
        One title per item (upper-cased in the built-in bitmap font).
    width, height : int, default 400
        Size of each tile.
    columns : int, optional
        Tiles per row (default: all in one row up to 6, then rows of 6).
    view : View, optional
        Camera for every tile.
    scalar_range : (float, float), optional
        Color range for scalar items.
    cmap : {"viridis", "coolwarm"}, default "viridis"
        Colormap for scalar items.

    Returns
    -------
    (H, W, 3) ndarray of uint8
        The panel.
    """
    items = list(items)
    if not items:
        raise ValueError("items is empty: nothing to render")
    if titles is not None and len(titles) != len(items):
        raise ValueError(f"titles has {len(titles)} entries for {len(items)} items")
    scalars = [np.asarray(c, dtype=np.float64) for _, _, c in items if c is not None]
    scalars = [c for c in scalars if c.ndim == 1]
    if scalars and scalar_range is None:
        scalar_range = (min(float(c.min()) for c in scalars), max(float(c.max()) for c in scalars))
    prepared = []
    for V, F, C in items:
        if C is not None and np.ndim(C) == 1:
            C = colormap(C, cmap, vmin=scalar_range[0], vmax=scalar_range[1])
        prepared.append((V, F, C))
    tiles = render_images(prepared, width=width, height=height, view=view)
    n = len(tiles)
    cols = min(n, 6) if columns is None else max(1, min(int(columns), n))
    rows = -(-n // cols)
    scale = max(1, round(width / 200))
    title_h = (7 * scale + 12) if titles else 0
    panel = np.full((rows * (height + title_h), cols * width, 3), 255, dtype=np.uint8)
    for i, tile in enumerate(tiles):
        r, c = divmod(i, cols)
        y0, x0 = r * (height + title_h), c * width
        if titles:
            text = str(titles[i])
            s = _fit_scale(text, width, scale)
            _draw_text(panel, text, x0 + (width - _text_width(text, s)) // 2, y0 + 6, s)
        panel[y0 + title_h : y0 + title_h + height, x0 : x0 + width] = tile
    if scalars:
        bar = _color_bar(panel.shape[1], cmap, scalar_range[0], scalar_range[1], scale)
        panel = np.concatenate([panel, bar], axis=0)
    if path is not None:
        write_png(path, panel)
    return panel


def write_png(path: str | os.PathLike[str], image: Any) -> None:
    """Write an (H, W, 3) or (H, W) uint8 image as a PNG, atomically (temp file + rename).

    Parameters
    ----------
    path : str or os.PathLike
        Destination.
    image : (H, W, 3) or (H, W) array_like of uint8
        RGB or grey pixels.
    """
    img = np.asarray(image)
    if img.dtype != np.uint8 or img.ndim not in (2, 3) or (img.ndim == 3 and img.shape[2] != 3):
        raise ValueError(f"image must be (H, W, 3) or (H, W) uint8; got {img.shape} {img.dtype}")
    h, w = img.shape[:2]
    color_type = 2 if img.ndim == 3 else 0
    rows = np.ascontiguousarray(img).reshape(h, -1)
    step = 3 if img.ndim == 3 else 1
    # Filter type 1 ("Sub"): each byte minus the same channel of the pixel to its left. Smooth
    # renders then compress 2-4x better than unfiltered rows.
    sub = rows.copy()
    sub[:, step:] = rows[:, step:] - rows[:, :-step]  # uint8 arithmetic wraps modulo 256
    raw = np.concatenate([np.ones((h, 1), dtype=np.uint8), sub], axis=1)

    def chunk(tag: bytes, data: bytes) -> bytes:
        return (
            struct.pack(">I", len(data))
            + tag
            + data
            + struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF)
        )

    png = (
        b"\x89PNG\r\n\x1a\n"
        + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, color_type, 0, 0, 0))
        + chunk(b"IDAT", zlib.compress(raw.tobytes(), 6))
        + chunk(b"IEND", b"")
    )
    with atomic_path(path, suffix=".png") as tmp, open(tmp, "wb") as fh:
        fh.write(png)


def read_png(path: str | os.PathLike[str]) -> np.ndarray:
    """Read a PNG written by :func:`write_png` (8-bit RGB or grey, row filters 0 and 1).

    Parameters
    ----------
    path : str or os.PathLike
        The file.

    Returns
    -------
    (H, W, 3) or (H, W) ndarray of uint8
        The pixels.
    """
    with open(os.fspath(path), "rb") as fh:
        data = fh.read()
    if data[:8] != b"\x89PNG\r\n\x1a\n":
        raise ValueError(f"{os.fspath(path)}: not a PNG file")
    pos, idat, header = 8, b"", None
    while pos + 8 <= len(data):
        (length,) = struct.unpack(">I", data[pos : pos + 4])
        tag, body = data[pos + 4 : pos + 8], data[pos + 8 : pos + 8 + length]
        if tag == b"IHDR":
            header = struct.unpack(">IIBBBBB", body)
        elif tag == b"IDAT":
            idat += body
        pos += 12 + length
    if header is None or header[2] != 8 or header[3] not in (0, 2) or header[6] != 0:
        raise ValueError(f"{os.fspath(path)}: only 8-bit non-interlaced RGB/grey PNGs are read")
    w, h, channels = header[0], header[1], 3 if header[3] == 2 else 1
    rows = np.frombuffer(zlib.decompress(idat), dtype=np.uint8).reshape(h, 1 + w * channels)
    if np.any(rows[:, 0] > 1):
        raise ValueError(f"{os.fspath(path)}: only PNG row filters 0 and 1 are supported")
    img = rows[:, 1:].copy()
    sub = rows[:, 0] == 1
    if np.any(sub):  # undo "Sub": running sum of each channel along the row, modulo 256
        lines = img[sub].reshape(int(sub.sum()), w, channels).astype(np.int64)
        img[sub] = (np.cumsum(lines, axis=1) % 256).astype(np.uint8).reshape(-1, w * channels)
    return img.reshape(h, w, 3) if channels == 3 else img.reshape(h, w)


def has_display() -> bool:
    """Whether a window can be opened (an X11 or Wayland display is set)."""
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def show(
    geometries: Sequence[Any],
    *,
    titles: Sequence[str] | None = None,
    fallback_path: str | os.PathLike[str] = "o3d_ofp_view.png",
) -> str | None:
    """Show Open3D geometries in a window, or write a PNG when there is no display.

    Parameters
    ----------
    geometries : sequence of Open3D TriangleMesh / PointCloud
        What to show (side by side in the PNG).
    titles : sequence of str, optional
        Titles for the PNG panel.
    fallback_path : str or os.PathLike, default "o3d_ofp_view.png"
        Where the PNG goes when no display exists.

    Returns
    -------
    str or None
        The PNG's path when one was written instead of opening a window, else ``None``.
    """
    from .adapters import geometry_to_arrays, require_open3d, vertex_colors

    if has_display():
        o3d = require_open3d()
        o3d.visualization.draw_geometries(list(geometries))
        return None
    items = []
    for g in geometries:
        V, F = geometry_to_arrays(g)
        items.append((V, F, vertex_colors(g)))
    render_panel(items, fallback_path, titles=titles)
    path = os.fspath(fallback_path)
    logger.warning("no display: wrote %s instead of opening a window", path)
    return path
