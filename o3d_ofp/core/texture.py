"""UV textures to per-vertex colors: bilinear sampling at the triangle corners' UVs."""

from __future__ import annotations

import logging
from typing import Any

import numpy as np

from ._validation import as_faces

__all__ = ["MAX_TEXTURE_SIZE", "TEXTURE_SIZE", "corner_colors_to_vertices", "sample_texture"]

#: Side of a baked texture image by default, in pixels.
TEXTURE_SIZE = 1024
#: Largest side of a baked texture image, in pixels (8192² RGB: 200 MB in float64 while baking).
MAX_TEXTURE_SIZE = 8192

logger = logging.getLogger(__name__)


def sample_texture(image: Any, uv: Any) -> np.ndarray:
    """Sample an image bilinearly at texture coordinates.

    Parameters
    ----------
    image : (H, W, C) or (H, W) array_like
        Texture; integer images are scaled from their dtype's range to [0, 1].
    uv : (m, 2) array_like of float
        Texture coordinates, OpenGL/OBJ convention: u to the right, v **up** (v = 0 is the
        bottom row of the image); coordinates outside [0, 1] wrap around (GL_REPEAT).

    Returns
    -------
    (m, C) ndarray of float64
        Sampled values (C = 1 for a grey image).
    """
    img = np.asarray(image)
    if img.ndim == 2:
        img = img[:, :, None]
    if img.ndim != 3 or img.shape[0] == 0 or img.shape[1] == 0:
        raise ValueError(f"image must have shape (H, W, C) or (H, W); got {np.shape(image)}")
    if np.issubdtype(img.dtype, np.integer):
        img = img.astype(np.float64) / np.iinfo(img.dtype).max
    else:
        img = img.astype(np.float64)
    t = np.asarray(uv, dtype=np.float64)
    if t.ndim != 2 or t.shape[1] != 2:
        raise ValueError(f"uv must have shape (m, 2); got {t.shape}")
    if not np.all(np.isfinite(t)):
        raise ValueError("uv holds NaN or inf texture coordinates")
    H, W = img.shape[:2]
    # Pixel centres sit at (i + 0.5) / W; wrap like GL_REPEAT.
    x = np.mod(t[:, 0], 1.0) * W - 0.5
    y = (1.0 - np.mod(t[:, 1], 1.0)) * H - 0.5
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    x0, y0 = x0.astype(np.int64), y0.astype(np.int64)
    xa, xb = np.mod(x0, W), np.mod(x0 + 1, W)
    ya, yb = np.mod(y0, H), np.mod(y0 + 1, H)
    top = img[ya, xa] * (1 - fx) + img[ya, xb] * fx
    bottom = img[yb, xa] * (1 - fx) + img[yb, xb] * fx
    return top * (1 - fy) + bottom * fy


def corner_colors_to_vertices(faces: Any, corner_colors: Any, n_vertices: int) -> np.ndarray:
    """Average per-corner values (one per triangle corner) onto the vertices.

    Parameters
    ----------
    faces : (m, 3) array_like of int
        Triangles.
    corner_colors : (3m, C) array_like of float
        Values at the corners, in the order ``faces.reshape(-1)``.
    n_vertices : int
        Number of vertices.

    Returns
    -------
    (n_vertices, C) ndarray of float64
        Mean of the corner values at each vertex (0 for a vertex no face uses).
    """
    F = as_faces(faces, n_vertices)
    c = np.asarray(corner_colors, dtype=np.float64)
    if c.ndim != 2 or c.shape[0] != 3 * F.shape[0]:
        raise ValueError(
            f"corner_colors must have shape (3m, C) = ({3 * F.shape[0]}, C); got {c.shape}"
        )
    idx = F.reshape(-1)
    out = np.zeros((n_vertices, c.shape[1]))
    np.add.at(out, idx, c)
    count = np.bincount(idx, minlength=n_vertices).astype(np.float64)
    spread = int(np.count_nonzero(count > 1))
    if spread:
        logger.debug("texture: %d vertices average several corner colors", spread)
    return out / np.maximum(count, 1.0)[:, None]
