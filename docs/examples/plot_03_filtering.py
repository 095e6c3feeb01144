"""
Smoothing and sharpening a shape
================================

:func:`o3d_ofp.filter_geometry` filters the vertex coordinates of a mesh or a point cloud
through the spectrum of its Laplacian. ``smooth`` is a radius, as a fraction of √area: detail
smaller than it is removed and the enclosed volume is kept. ``sharpen`` multiplies the detail
smaller than ``smooth`` by ``1 + sharpen``. Here a procedural shape gets noise, which
smoothing removes, and a smooth shape with ripples gets its ripples enhanced.
"""

# %%
# A noisy shape
# -------------
# A blob with noise along the radial direction, of standard deviation 1 % of √area (the shape's
# length scale, which does not depend on its resolution).
import matplotlib.pyplot as plt
import numpy as np

import o3d_ofp as ofp
from o3d_ofp.core.shapes import blob
from o3d_ofp.render import View

clean, faces = blob(4)  # 2562 vertices
root_area = np.sqrt(ofp.eigenbasis(clean, faces, k=1).area)
radial = clean / np.linalg.norm(clean, axis=1, keepdims=True)
rng = np.random.default_rng(0)
noisy = clean + radial * rng.normal(0.0, 0.01 * root_area, len(clean))[:, None]


def distance(a, b):
    """Mean distance between corresponding vertices, / √area of the clean shape."""
    return np.linalg.norm(a - b, axis=1).mean() / root_area


def volume(v, f):
    """Enclosed volume of a closed, outward-oriented triangle mesh."""
    return np.einsum("ij,ij->i", v[f[:, 0]], np.cross(v[f[:, 1]], v[f[:, 2]])).sum() / 6.0


print(f"noisy: distance to the clean shape {distance(noisy, clean):.4f}")

# %%
# Smoothing
# ---------
# The input may be an Open3D geometry or, as here, a ``(vertices, faces)`` tuple; the result is
# a new Open3D mesh. A radius below the spacing of the vertices (about 2 % of √area at this
# resolution) leaves the noise; a larger one removes it (and, larger still, gains nothing: it
# starts to take the blob's own bumps too). The volume stays that of the input.
smoothed = {}
for radius in (0.005, 0.02, 0.04):
    mesh = ofp.filter_geometry((noisy, faces), smooth=radius)
    smoothed[radius] = np.asarray(mesh.vertices)
    print(
        f"smooth={radius:<5}: distance to the clean shape "
        f"{distance(smoothed[radius], clean):.4f}, volume / noisy volume "
        f"{volume(smoothed[radius], faces) / volume(noisy, faces):.4f}"
    )

# %%
view = View(front=(0.2, -0.4, 1.0))
items = [(clean, faces, None), (noisy, faces, None)]
items += [(v, faces, None) for v in smoothed.values()]
titles = ["clean", "noisy"] + [f"smooth={r}" for r in smoothed]
panel = ofp.render_panel(items, titles=titles, width=300, height=300, view=view)
fig, ax = plt.subplots(figsize=(10, 2.6))
ax.imshow(panel)
ax.set_axis_off()
fig.tight_layout()

# %%
# Sharpening
# ----------
# A blob with ripples (a product of sines of the coordinates, along the radial direction).
# Sharpening is unsharp masking: the detail is the difference between the shape and its
# low-pass at radius ``smooth`` (:func:`o3d_ofp.core.filtering.lowpass`, a Butterworth filter
# of the Laplacian), and ``sharpen=1`` adds it once more, so that it doubles. The
# measure below is the mean length of the detail vectors before and after.
from o3d_ofp.core.filtering import lowpass

rippled = clean + radial * (0.03 * np.sin(10 * clean[:, 0]) * np.sin(10 * clean[:, 1]))[:, None]
sharpened = np.asarray(ofp.filter_geometry((rippled, faces), sharpen=1.0, smooth=0.05).vertices)
base = lowpass(ofp.eigenbasis(rippled, faces, k=1), rippled, smooth=0.05)
before = np.linalg.norm(rippled - base, axis=1).mean()
after = np.linalg.norm(sharpened - base, axis=1).mean()
print(
    f"detail before {before / root_area:.4f}, after {after / root_area:.4f} "
    f"(/ sqrt(area)): x {after / before:.3f}"
)

# %%
# The low-pass :func:`o3d_ofp.filter_geometry` returns with ``smooth=0.05``, the rippled
# shape and the sharpened one:
low_pass = np.asarray(ofp.filter_geometry((rippled, faces), smooth=0.05).vertices)
panel = ofp.render_panel(
    [(low_pass, faces, None), (rippled, faces, None), (sharpened, faces, None)],
    titles=["low-pass (smooth=0.05)", "rippled", "sharpen=1"],
    width=320,
    height=320,
    view=view,
)
fig, ax = plt.subplots(figsize=(9, 3.3))
ax.imshow(panel)
ax.set_axis_off()
fig.tight_layout()
plt.show()
