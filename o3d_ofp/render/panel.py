"""Headless pictures: lit renders of meshes and point clouds, side by side, with titles.

Rendering uses Open3D's legacy ``Visualizer`` with a hidden window, which runs over EGL
(Mesa) without a display, in a **separate interpreter** (:mod:`._worker`, run by path, arrays
exchanged through a temporary ``.npz``): when no OpenGL context can be created,
``create_window`` returns False and the next call would crash the interpreter, so a crash
or a hang there must not take the caller down. ``open3d.visualization.rendering.
OffscreenRenderer`` is not used (in Open3D 0.20 its Vulkan/Filament backend aborts or hangs on
a CPU-only machine), nor ``draw_geometries`` without a display (it blocks forever).

Each tile is framed on its own geometry (see :mod:`._worker`), rendered at twice its size and
reduced (smooth edges). The panel is composed with Pillow: titles in DejaVu Sans (the font
matplotlib ships), and for scalar fields a color bar drawn by matplotlib with its tick values and
an optional label. Colormaps are matplotlib's (any registered name). PNG files are read and
written by Pillow, atomically. Matplotlib and Pillow are imported only when needed.
"""

from __future__ import annotations

import dataclasses
import functools
import io
import logging
import math
import os
import subprocess
import sys
import tempfile
from collections.abc import Sequence
from subprocess import DEVNULL, PIPE
from typing import Any

import numpy as np

from ..core._atomic import atomic_path
from ..core._validation import as_faces, as_signal, as_vertices, check_int
from . import _worker

# The names o3d_ofp.render re-exports; the CLI also imports MIN_SIDE, MAX_SIDE and geometry_items.
__all__ = [
    "RenderError",
    "RenderUnavailable",
    "View",
    "colormap",
    "read_png",
    "render_images",
    "render_panel",
    "show",
    "write_png",
]

logger = logging.getLogger(__name__)

_WORKER = os.path.abspath(_worker.__file__)
#: Largest value accepted in float RGB colors (which are in [0, 1]; above 1 they are clipped):
#: colors transferred between shapes overshoot a little (their basis' ringing, a few
#: hundredths), 0-255 colors by two orders of magnitude. Between the two, a scale mistake is
#: refused rather than drawn white.
RGB_MAX = 2.0
#: Tile sides accepted, in pixels.
MIN_SIDE, MAX_SIDE = 16, 8192


class RenderError(RuntimeError):
    """No picture could be rendered (no OpenGL/EGL context, or the renderer crashed or hung)."""


class RenderUnavailable(RenderError):
    """Rendering is impossible here: no OpenGL/EGL context can be created, or no Open3D.

    A subclass of :class:`RenderError`; a renderer that *crashes* raises plain
    :class:`RenderError` instead, so callers (and tests) can tell "cannot render here" from
    "broken".
    """


def _mpl_colormap(name: Any) -> Any:
    import matplotlib
    from matplotlib.colors import Colormap

    if isinstance(name, Colormap):
        return name
    try:
        return matplotlib.colormaps[name]
    except (KeyError, TypeError, ValueError):
        raise ValueError(
            "colormap must be one of matplotlib's registered colormaps (e.g. 'viridis', "
            f"'coolwarm', 'magma', 'RdBu_r'); got {name!r}"
        ) from None


def colormap(
    values: Any,
    name: str = "viridis",
    *,
    vmin: float | None = None,
    vmax: float | None = None,
) -> np.ndarray:
    """Map scalar values to RGB colors with a matplotlib colormap.

    Parameters
    ----------
    values : (n,) array_like of float
        Scalars.
    name : str or matplotlib.colors.Colormap, default "viridis"
        Any colormap registered with matplotlib ("viridis", "coolwarm", "magma", "RdBu_r", ...).
    vmin, vmax : float, optional
        Range mapped to the ends of the map (default: the values' min and max); values outside
        are clipped. A constant field (``vmax <= vmin``) gets the map's middle color.

    Returns
    -------
    (n, 3) ndarray of float64
        Colors in [0, 1].

    Raises
    ------
    ValueError
        For an unknown colormap name, or values that are not one finite scalar per vertex.
    """
    cmap = _mpl_colormap(name)
    v = as_signal(values, np.shape(values)[0] if np.ndim(values) else 0, name="values")
    if v.ndim != 1:
        raise ValueError(f"values must be one scalar per vertex, shape (n,); got {v.shape}")
    if v.size == 0:
        return np.zeros((0, 3))
    lo = float(v.min()) if vmin is None else float(vmin)
    hi = float(v.max()) if vmax is None else float(vmax)
    t = np.clip((v - lo) / (hi - lo), 0.0, 1.0) if hi > lo else np.full(v.shape, 0.5)
    return np.asarray(cmap(t), dtype=np.float64)[:, :3]


@dataclasses.dataclass(frozen=True)
class View:
    """Camera direction for a render: the shape is seen from ``front``, ``up`` pointing up.

    Every tile is framed on its own shape: the camera looks at the shape's centre from
    direction ``front`` and is placed so that the whole shape is inside the tile, wherever the
    shape is and whatever its size.

    Attributes
    ----------
    front : (3,) tuple of float
        Direction from the shape's centre towards the camera.
    up : (3,) tuple of float
        Up direction on screen (must not be parallel to ``front``).
    zoom : float
        Smaller is closer. At the default 0.6 the shape fills 90% of the tile's width or height
        (whichever it reaches first); the picture scales as ``0.6 / zoom`` (at 0.54 it touches
        the tile's edges, below that it is cropped).
    """

    front: tuple[float, float, float] = (0.0, 0.0, 1.0)
    up: tuple[float, float, float] = (0.0, 1.0, 0.0)
    zoom: float = 0.6

    def check(self) -> None:
        """Raise ValueError for a bad view (see the attributes) before any rendering."""
        self._checked()

    def _checked(self) -> tuple[np.ndarray, np.ndarray, float]:
        front, up = (np.asarray(v, dtype=np.float64).reshape(-1) for v in (self.front, self.up))
        for name, vec in (("front", front), ("up", up)):
            if vec.shape != (3,) or not np.all(np.isfinite(vec)) or np.linalg.norm(vec) == 0:
                raise ValueError(f"View.{name} must be a finite non-zero 3-vector; got {vec}")
        cos = abs(front @ up) / (np.linalg.norm(front) * np.linalg.norm(up))
        if cos > 1.0 - 1e-9:
            raise ValueError(f"View.up {self.up} is parallel to View.front {self.front}")
        zoom = float(self.zoom)
        if not (math.isfinite(zoom) and zoom > 0.0):
            raise ValueError(f"View.zoom must be a positive number; got {self.zoom!r}")
        return front, up, zoom


def _texture(texture: Any, n_faces: int) -> tuple[np.ndarray, np.ndarray]:
    try:
        uv, image = texture
    except (TypeError, ValueError):
        raise ValueError("a texture must be a pair (uv, image)") from None
    uv = np.array(uv, dtype=np.float64)
    if uv.shape != (3 * n_faces, 2):
        raise ValueError(
            f"texture uv must have shape (3m, 2) = ({3 * n_faces}, 2), one per triangle corner; "
            f"got {uv.shape}"
        )
    if not np.all(np.isfinite(uv)):
        raise ValueError("texture uv holds NaN or inf")
    img = np.asarray(image)
    if img.ndim == 2:
        img = np.repeat(img[:, :, None], 3, axis=2)
    if img.ndim != 3 or img.shape[2] not in (3, 4) or img.size == 0:
        raise ValueError(f"texture image must be (H, W, 3), (H, W, 4) or (H, W); got {img.shape}")
    img = img[:, :, :3]
    if img.dtype != np.uint8:
        if not np.issubdtype(img.dtype, np.floating):
            raise ValueError(f"texture image must be uint8 or float in [0, 1]; got {img.dtype}")
        img = (np.clip(np.nan_to_num(img), 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
    return uv, np.ascontiguousarray(img)


def _item(vertices: Any, faces: Any, colors: Any, texture: Any = None) -> dict[str, np.ndarray]:
    """Check an item; return v, c (RGB, or scalars to map), f (mesh), uv and tex (texture)."""
    V = as_vertices(vertices)
    item = {"v": V, "c": np.full((V.shape[0], 3), 0.7)}
    if faces is not None:
        item["f"] = as_faces(faces, V.shape[0])
    if colors is not None:
        C = as_signal(colors, V.shape[0], name="colors")
        if C.ndim == 2 and C.shape[1] != 3:
            raise ValueError(f"colors must have shape (n, 3) or (n,); got {C.shape}")
        if C.ndim == 2 and np.asarray(colors).dtype == np.uint8:
            C = C / 255.0  # 8-bit RGB, as images hold them
        elif C.ndim == 2 and C.max() > RGB_MAX:
            raise ValueError(
                f"colors holds values up to {C.max():g}: RGB colors are in [0, 1] (divide "
                "0-255 colors by 255, or pass them as uint8); scalars to color-map are (n,)"
            )  # fmt: skip
        item["c"] = C if C.ndim == 1 else np.clip(C, 0.0, 1.0)
    if texture is not None:
        if faces is None:
            raise ValueError("a texture needs a mesh (faces), not a point cloud")
        item["uv"], item["tex"] = _texture(texture, item["f"].shape[0])
    return item


def _items(items: Sequence[Any], textures: Sequence[Any] | None) -> list[dict[str, np.ndarray]]:
    """Check the items; an Open3D geometry gives its arrays, colors and own texture."""
    items = list(items)
    if not items:
        raise ValueError("items is empty: nothing to render")
    textures = [None] * len(items) if textures is None else list(textures)
    if len(textures) != len(items):
        raise ValueError(f"textures has {len(textures)} entries for {len(items)} items")
    checked = []
    for i, (item, texture) in enumerate(zip(items, textures, strict=True)):
        if not isinstance(item, (tuple, list)):
            from ..boundary.convert import is_open3d_geometry

            if not is_open3d_geometry(item):
                raise TypeError(f"items[{i}] must be (vertices, faces, colors) or an Open3D "
                                f"geometry; got {type(item).__name__}")  # fmt: skip
            (item,), (own,) = geometry_items([item])
            texture = own if texture is None else texture
        elif len(item) != 3:
            raise TypeError(f"items[{i}] must be (vertices, faces, colors): 3 entries (faces "
                            f"None for points, colors None for grey); got {len(item)}")  # fmt: skip
        checked.append(_item(*item, texture))
    return checked


def render_images(
    items: Sequence[tuple[Any, Any, Any]],
    *,
    textures: Sequence[tuple[Any, Any] | None] | None = None,
    width: int = 600,
    height: int = 600,
    view: View | None = None,
    point_size: float | None = None,
    timeout: float = 300.0,
) -> list[np.ndarray]:
    """Render meshes or point clouds, one image each, in a child process.

    Parameters
    ----------
    items : sequence of (vertices, faces, colors) or Open3D geometries
        ``vertices`` (n, 3); ``faces`` (m, 3) or ``None`` for points; ``colors`` (n, 3) RGB
        in [0, 1] (uint8: 0-255), (n,) scalars (mapped with "viridis"), or ``None`` (grey).
        An Open3D mesh or point cloud is drawn with its vertex colors, or its own texture.
    textures : sequence of (uv, image) or None, optional
        One entry per item (``None`` for an item without texture). ``uv`` (3m, 2): texture
        coordinates of each triangle corner (``uv[3 * t + k]`` for corner ``k`` of triangle
        ``t``), ``v`` pointing up the image (the OBJ convention: the image's first row is at
        ``v = 1``); ``image`` (H, W, 3) uint8 (or (H, W), (H, W, 4), or floats in [0, 1]). A
        textured mesh is drawn with its texture (Open3D's textured shader) and its ``colors``
        are not used.
    width, height : int, default 600
        Image size in pixels.
    view : View, optional
        Camera direction (default: looking along −z with y up); each item is framed on its own.
    point_size : float, optional
        Point size in pixels for point clouds (default: 3 at 400 pixels, scaled with the size).
    timeout : float, default 300
        Seconds before the renderer is considered hung and killed.

    Returns
    -------
    list of (height, width, 3) ndarray of uint8
        One lit render per item, white background.

    Raises
    ------
    RenderUnavailable
        When no OpenGL context can be created (no EGL library, no display) or Open3D cannot be
        imported.
    RenderError
        When the renderer crashes or hangs.
    """
    return _render(_items(items, textures), width, height, view, point_size, timeout)


def _render(
    items: list[dict[str, np.ndarray]],
    width: int,
    height: int,
    view: View | None,
    point_size: float | None,
    timeout: float,
) -> list[np.ndarray]:
    """Render checked items (:func:`_item`; scalars left are mapped with "viridis")."""
    width = check_int(width, name="width", minimum=MIN_SIDE, maximum=MAX_SIDE)
    height = check_int(height, name="height", minimum=MIN_SIDE, maximum=MAX_SIDE)
    front, up, zoom = (view or View())._checked()
    if point_size is None:
        point_size = max(3.0, 3.0 * min(width, height) / 400.0)
    arrays: dict[str, Any] = dict(count=len(items), width=width, height=height, front=front, up=up)
    # fill: the fraction of the tile the shape spans, 0.9 at the default zoom 0.6
    arrays.update(fill=0.9 * 0.6 / zoom, point_size=float(point_size))
    arrays.update({f"{key}{i}": a for i, item in enumerate(items) for key, a in item.items()})
    for i, item in enumerate(items):
        if item["c"].ndim == 1:
            arrays[f"c{i}"] = colormap(item["c"])
    with tempfile.TemporaryDirectory(prefix="o3d_ofp_render.") as tmp:
        inp, out = os.path.join(tmp, "in.npz"), os.path.join(tmp, "out.npz")
        np.savez(inp, **arrays)
        cmd = [sys.executable, _WORKER, inp, out]
        try:  # stdout: Open3D's and EGL's console chatter
            proc = subprocess.run(cmd, stdin=DEVNULL, stdout=DEVNULL, stderr=PIPE, timeout=timeout)
        except subprocess.TimeoutExpired:
            raise RenderError(f"the renderer did not answer within {timeout:g} s") from None
        tail = proc.stderr.decode(errors="replace").strip().splitlines()[-1:]
        if proc.returncode == _worker.NO_CONTEXT:
            raise RenderUnavailable(
                "no OpenGL context: create_window failed (on Debian: apt-get install libgl1 "
                "libegl1)"
            )
        if proc.returncode == _worker.NO_OPEN3D:
            from ..boundary.convert import OPEN3D_INSTALL_HINT

            why = tail[0] if tail else "open3d cannot be imported"
            raise RenderUnavailable(f"{why}; install: {OPEN3D_INSTALL_HINT}")
        if proc.returncode != 0 or not os.path.isfile(out):
            why = f": {tail[0]}" if tail else ""
            raise RenderError(f"the renderer process failed (exit status {proc.returncode}){why}")
        with np.load(out, allow_pickle=False) as images:
            return [images[f"img{i}"] for i in range(len(items))]


@functools.lru_cache(maxsize=64)
def _font(size: int) -> Any:
    """DejaVu Sans (shipped with matplotlib) at ``size`` pixels."""
    import matplotlib
    from PIL import ImageFont

    path = os.path.join(matplotlib.get_data_path(), "fonts", "ttf", "DejaVuSans.ttf")
    return ImageFont.truetype(path, size)


def _draw_centered(draw: Any, text: str, box: tuple[int, int, int, int], size: int) -> None:
    """Draw ``text`` centred in ``box`` (x0, y0, x1, y1), shrinking or cutting it to fit."""
    x0, y0, x1, y1 = box
    room = x1 - x0 - 8
    while size > 9 and draw.textbbox((0, 0), text, font=_font(size))[2] > room:
        size -= 1
    while len(text) > 1 and draw.textbbox((0, 0), text, font=_font(size))[2] > room:
        text = text[:-2] + "…"
    left, top, right, bottom = draw.textbbox((0, 0), text, font=_font(size))
    x = x0 + (x1 - x0 - (right - left)) // 2 - left
    y = y0 + (y1 - y0 - (bottom - top)) // 2 - top
    draw.text((x, y), text, font=_font(size), fill=(20, 20, 20))


def _title_size(width: int) -> int:
    return int(min(40, max(12, round(0.045 * width))))


def _colorbar(
    width: int, tile: int, cmap: Any, vmin: float, vmax: float, label: str | None
) -> np.ndarray:
    """Draw a horizontal color bar with tick values (and ``label`` below), ``width`` wide."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import Normalize
    from matplotlib.figure import Figure

    if not vmax > vmin:  # a constant field: its value in the middle of the bar
        half = 0.5 * max(abs(vmin), 1.0)
        vmin, vmax = vmin - half, vmax + half
    font_px = 0.8 * _title_size(tile)
    bar_px = max(12, round(0.3 * font_px + 0.025 * tile))
    pad = round(0.5 * font_px)
    # rows: pad, the bar, its tick values (2 font heights), the label (1.6), pad
    height = round(pad + bar_px + 2.0 * font_px + (1.6 * font_px if label else 0.0) + pad)
    length = (0.8 if width <= 2 * tile else 0.6) * width
    length = min(length, width - 4 * font_px) if width > 8 * font_px else 0.9 * width
    dpi = 100.0
    fig = Figure(figsize=(width / dpi, height / dpi), dpi=dpi, facecolor="white")
    canvas = FigureCanvasAgg(fig)
    box = ((width - length) / 2 / width, 1.0 - (pad + bar_px) / height, length / width)
    cax = fig.add_axes((*box, bar_px / height))
    mappable = ScalarMappable(norm=Normalize(vmin=vmin, vmax=vmax), cmap=_mpl_colormap(cmap))
    bar = fig.colorbar(mappable, cax=cax, orientation="horizontal")
    points = font_px * 72.0 / dpi
    bar.ax.tick_params(labelsize=points, length=0.35 * font_px, width=1.0, color="0.2")
    bar.outline.set_linewidth(0.8)
    if label:
        bar.set_label(label, fontsize=points * 1.15, color="0.1", labelpad=0.25 * font_px)
    canvas.draw()
    return np.asarray(canvas.buffer_rgba())[:, :, :3].copy()


def render_panel(
    items: Sequence[tuple[Any, Any, Any]],
    path: str | os.PathLike[str] | None = None,
    *,
    titles: Sequence[str] | None = None,
    width: int = 600,
    height: int = 600,
    columns: int | None = None,
    view: View | None = None,
    scalar_range: tuple[float, float] | None = None,
    cmap: str = "viridis",
    colorbar_label: str | None = None,
    textures: Sequence[tuple[Any, Any] | None] | None = None,
    point_size: float | None = None,
) -> np.ndarray:
    """Render several shapes side by side with titles (like the paper's figures).

    Parameters
    ----------
    items : sequence of (vertices, faces, colors)
        As in :func:`~o3d_ofp.render.render_images`. Scalar ``colors`` share one color scale
        across the panel (``scalar_range``, default the min and max over all scalar items) and
        add a color bar with tick values under the tiles.
    path : str or os.PathLike, optional
        Where to write the panel as a PNG (atomically).
    titles : sequence of str, optional
        One title per item, drawn above its tile.
    width, height : int, default 600
        Size of each tile in pixels.
    columns : int, optional
        Tiles per row (default: all in one row up to 6, then rows of 6).
    view : View, optional
        Camera direction for every tile; each tile is framed on its own shape.
    scalar_range : (float, float), optional
        Color range for scalar items.
    cmap : str, default "viridis"
        Matplotlib colormap for scalar items ("viridis", "coolwarm", "magma", ...).
    colorbar_label : str, optional
        Text under the color bar (e.g. "relative error").
    textures : sequence of (uv, image) or None, optional
        Per-item UV textures, as in :func:`~o3d_ofp.render.render_images`.
    point_size : float, optional
        Point size for point clouds, as in :func:`~o3d_ofp.render.render_images`.

    Returns
    -------
    (H, W, 3) ndarray of uint8
        The panel.

    Examples
    --------
    Two tiles of 64 × 64 pixels, colored by the z and x coordinates on one color scale:

    >>> import os
    >>> import tempfile
    >>> import numpy as np
    >>> import open3d as o3d
    >>> import o3d_ofp as ofp
    >>> sphere = o3d.geometry.TriangleMesh.create_sphere(radius=1.0, resolution=10)
    >>> V, F = np.asarray(sphere.vertices), np.asarray(sphere.triangles)
    >>> with tempfile.TemporaryDirectory() as folder:
    ...     path = os.path.join(folder, "panel.png")
    ...     panel = ofp.render_panel(
    ...         [(V, F, V[:, 2]), (V, F, V[:, 0])], path, titles=["z", "x"], width=64, height=64
    ...     )
    ...     os.path.exists(path)
    True
    >>> panel.dtype, panel.shape[1], panel.shape[2]
    (dtype('uint8'), 128, 3)
    """
    from PIL import Image, ImageDraw

    if path is not None:
        _check_png_path(path)  # before the rendering
    checked = _items(items, textures)
    if titles is not None and len(titles) != len(checked):
        raise ValueError(f"titles has {len(titles)} entries for {len(checked)} items")
    _mpl_colormap(cmap)  # an unknown name fails before rendering
    scalars = [item for item in checked if item["c"].ndim == 1 and "tex" not in item]
    if scalar_range is not None:
        lo, hi = (float(x) for x in scalar_range)
        if not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi):
            raise ValueError(f"scalar_range must be finite (low, high); got {scalar_range!r}")
    elif scalars:
        values = np.concatenate([item["c"] for item in scalars])
        lo, hi = float(values.min()), float(values.max())
    for item in scalars:
        item["c"] = colormap(item["c"], cmap, vmin=lo, vmax=hi)
    tiles = _render(checked, width, height, view, point_size, 300.0)
    height, width = tiles[0].shape[:2]
    n = len(tiles)
    cols = min(n, 6) if columns is None else max(1, min(int(columns), n))
    size = _title_size(width)
    title_h = round(1.7 * size) if titles else 0
    canvas = Image.new("RGB", (cols * width, -(-n // cols) * (height + title_h)), (255, 255, 255))
    draw = ImageDraw.Draw(canvas)
    for i, tile in enumerate(tiles):
        y0, x0 = i // cols * (height + title_h), i % cols * width
        if titles:
            _draw_centered(draw, str(titles[i]), (x0, y0, x0 + width, y0 + title_h), size)
        canvas.paste(Image.fromarray(tile), (x0, y0 + title_h))
    panel = np.asarray(canvas, dtype=np.uint8).copy()
    if scalars:
        bar = _colorbar(panel.shape[1], width, cmap, lo, hi, colorbar_label)
        panel = np.concatenate([panel, bar], axis=0)
    if path is not None:
        write_png(path, panel)
    return panel


def _png_bytes(image: np.ndarray) -> bytes:
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(image).save(buf, format="PNG", optimize=False, compress_level=6)
    return buf.getvalue()


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
    _check_png_path(path)
    with atomic_path(path, suffix=".png") as tmp, open(tmp, "wb") as fh:
        fh.write(_png_bytes(img))


def _check_png_path(path: str | os.PathLike[str]) -> None:
    """Refuse a file name that does not end in ``.png`` (what is written is a PNG)."""
    if not os.fspath(path).lower().endswith(".png"):
        raise ValueError(f"path {os.fspath(path)!r}: the picture is written as PNG; give a name "
                         "ending in .png")  # fmt: skip


def read_png(path: str | os.PathLike[str]) -> np.ndarray:
    """Read a PNG (or any image Pillow reads) as 8-bit RGB or grey pixels.

    Parameters
    ----------
    path : str or os.PathLike
        The file.

    Returns
    -------
    (H, W, 3) or (H, W) ndarray of uint8
        The pixels: grey images stay (H, W); palette, alpha and other modes become RGB.
    """
    from PIL import Image

    with Image.open(os.fspath(path)) as im:
        grey = im.mode in ("1", "L", "LA", "I", "I;16", "I;16B", "I;16L")
        return np.array(im.convert("L" if grey else "RGB"), dtype=np.uint8)


def in_notebook() -> bool:
    """Whether the code runs in a Jupyter (IPython kernel) session."""
    try:
        shell = sys.modules["IPython"].get_ipython()
    except Exception:  # IPython not imported, or broken: not a notebook
        return False
    return getattr(shell, "kernel", None) is not None


def geometry_items(geometries: Sequence[Any]) -> tuple[list[tuple[Any, Any, Any]], list[Any]]:
    """Return the arrays (and UV texture, when an Open3D mesh has one) of each geometry.

    Parameters
    ----------
    geometries : sequence of Open3D geometries
        Meshes and point clouds (not modified).

    Returns
    -------
    items : list of (vertices (n, 3), faces (m, 3) or None, colors (n, 3) or None)
        As :func:`~o3d_ofp.render.render_images` takes them.
    textures : list of (uv (3m, 2), image) or None
        As :func:`~o3d_ofp.render.render_images` takes them (None for an untextured geometry).
    """
    from ..boundary.convert import geometry_to_arrays, vertex_colors
    from ..boundary.texture import mesh_texture

    items, textures = [], []
    for g in geometries:
        V, F = geometry_to_arrays(g)
        colors, texture = vertex_colors(g), None
        try:  # a mesh's own texture, read the way every other function reads it
            tex = None if F is None else mesh_texture(g)
        except (TypeError, ValueError):  # no UVs or no image
            tex = None
        if tex is not None:
            used = np.unique(tex.material)
            if used.size == 1 and used[0] >= 0:
                texture = (tex.uvs.reshape(-1, 2), tex.images[int(used[0])])
            else:  # several images: sample them into vertex colors
                colors = tex.vertex_colors()
        items.append((V, F, colors))
        textures.append(texture)
    return items, textures


def show(
    geometries: Sequence[Any],
    *,
    titles: Sequence[str] | None = None,
    fallback_path: str | os.PathLike[str] = "o3d_ofp_view.png",
    width: int = 600,
    height: int = 600,
    view: View | None = None,
) -> str | None:
    """Show Open3D geometries: inline in Jupyter, in a window, or as a PNG file.

    In a Jupyter notebook (an IPython kernel) the geometries are rendered side by side and the
    picture is displayed inline. Elsewhere, with a display (``DISPLAY`` or ``WAYLAND_DISPLAY``
    set, or macOS or Windows), Open3D's viewer window opens. Otherwise the picture is written
    to ``fallback_path``.

    Parameters
    ----------
    geometries : Open3D TriangleMesh / PointCloud, or a sequence of them
        What to show (side by side in a picture). Vertex colors are used; a legacy mesh with
        a UV texture (e.g. read from an OBJ with its material) is drawn textured.
    titles : sequence of str, optional
        Titles for the picture's tiles.
    fallback_path : str or os.PathLike, default "o3d_ofp_view.png"
        Where the PNG goes when there is neither a notebook nor a display.
    width, height : int, default 600
        Tile size of the picture.
    view : View, optional
        Camera direction of the picture.

    Returns
    -------
    str or None
        The PNG's path when one was written, else ``None`` (shown inline or in a window).
    """
    from ..boundary.convert import is_open3d_geometry, require_open3d
    from ..boundary.pick import has_display

    geoms = [geometries] if is_open3d_geometry(geometries) else list(geometries)
    notebook = in_notebook()
    if has_display() and not notebook:
        require_open3d().visualization.draw_geometries(geoms)
        return None
    if not notebook:
        _check_png_path(fallback_path)  # before the rendering
    items, textures = geometry_items(geoms)
    panel = render_panel(
        items, titles=titles, width=width, height=height, view=view, textures=textures
    )
    if notebook:
        from IPython.display import Image, display

        display(Image(data=_png_bytes(panel), format="png"))
        return None
    write_png(fallback_path, panel)
    logger.warning("no display: wrote %s instead of opening a window", os.fspath(fallback_path))
    return os.fspath(fallback_path)
