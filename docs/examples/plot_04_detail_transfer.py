"""
Transferring geometric detail
=============================

:func:`o3d_ofp.transfer_detail` gives a target shape the geometric detail of a source shape:
the detail the target lacks is measured on the source above the low-pass the target resembles
most, carried through the map, and re-applied in the target's own local frames, so that it
follows the target's pose. Here the source is a sphere with bumps and the target a smooth,
bent sphere; the bent bumpy sphere is the truth the result is compared with.
"""

# %%
# Source, target and truth
# ------------------------
# The bumps are two Legendre polynomials (degrees 10 and 9) of the coordinates, along the
# normal. The target is the smooth sphere bent by ``y += 0.4 x²``; the truth is the bumpy
# sphere bent the same way. The three meshes share their triangulation.
import matplotlib.pyplot as plt
import numpy as np
from numpy.polynomial import legendre

import o3d_ofp as ofp
from o3d_ofp.core.shapes import icosphere
from o3d_ofp.render import View

sphere, faces = icosphere(4)  # 2562 vertices on the unit sphere
x, y, z = sphere.T
bumps = 0.1 * (legendre.legval(z, [0] * 10 + [1]) + legendre.legval(x, [0] * 9 + [1]))
bumpy = sphere * (1.0 + bumps)[:, None]


def bend(v):
    out = v.copy()
    out[:, 1] += 0.4 * out[:, 0] ** 2
    return out


target, truth = bend(sphere), bend(bumpy)
root_area = np.sqrt(ofp.eigenbasis(target, faces, k=1).area)


def distance(a, b):
    """Mean distance between corresponding vertices, / √area of the target."""
    return np.linalg.norm(a - b, axis=1).mean() / root_area


print(f"target: distance to the truth {distance(target, truth):.4f}")

# %%
# The map
# -------
# The shapes share their vertices, so the map is known: vertex ``j`` of the target is vertex
# ``j`` of the source. :meth:`o3d_ofp.Correspondence.from_p2p` wraps it. (A sphere is too
# symmetric for :func:`o3d_ofp.match` to find *the* map; between shapes without a known map,
# ``match`` gives one, as in the previous example.)
identity = ofp.Correspondence.from_p2p(np.arange(len(target)), (bumpy, faces), (target, faces))

# %%
# Calibrated transfer and a fixed band
# ------------------------------------
# By default (``mode="add"``, ``band=None``) the detail is calibrated: the source's low-pass the
# target resembles most is found, and what the source has above it is added. ``band=24``
# instead takes the detail above the first 24 eigenfunctions, which on the sphere are exactly
# the spherical harmonics of degree 1 to 4 (3 + 5 + 7 + 9 functions).
calibrated = ofp.transfer_detail((bumpy, faces), (target, faces), correspondence=identity)
banded = ofp.transfer_detail((bumpy, faces), (target, faces), correspondence=identity, band=24)
results = {"calibrated": np.asarray(calibrated.vertices), "band=24": np.asarray(banded.vertices)}
for name, v in results.items():
    d = distance(v, truth)
    print(
        f"{name:10s}: distance to the truth {d:.4f} "
        f"({d / distance(target, truth):.2f} of the target's)"
    )

# %%
# From left to right: the source, the target, the two results and the truth.
view = View(front=(0.3, -0.3, 1.0))
items = [(bumpy, faces, None), (target, faces, None)]
items += [(v, faces, None) for v in results.values()] + [(truth, faces, None)]
titles = ["source", "target", "calibrated", "band=24", "truth"]
panel = ofp.render_panel(items, titles=titles, width=300, height=300, view=view)
fig, ax = plt.subplots(figsize=(10, 2.6))
ax.imshow(panel)
ax.set_axis_off()
fig.tight_layout()
plt.show()
