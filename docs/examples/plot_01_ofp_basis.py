"""
Approximating a color signal with an OFP basis
==============================================

The Orthogonalized Fourier Polynomials of a shape are the pointwise products of its first
Laplace-Beltrami eigenfunctions, orthonormalized under the area-weighted inner product. This
example builds them on a procedural shape and compares three bases on one color signal: the
30 eigenfunctions the products come from, the OFP basis with the "ours" threshold and the
larger one with "ours*".
"""

# %%
# A shape and a signal
# --------------------
# ``o3d_ofp.core.shapes.blob`` is an icosphere pushed in and out by a few smooth random
# bumps: a closed surface without symmetry, made from arrays alone (no data file). The color
# signal has smooth bands (red, green) and sharp-edged stripes (blue) that no small set of
# smooth functions can follow exactly.
import matplotlib.pyplot as plt
import numpy as np

import o3d_ofp as ofp
from o3d_ofp.core.shapes import blob
from o3d_ofp.render import View
from o3d_ofp.workflows.demo import demo_signal

vertices, faces = blob(4)  # 2562 vertices
colors = demo_signal(vertices)  # the demo's pattern: smooth bands, sharp stripes
print(f"{vertices.shape[0]} vertices, {faces.shape[0]} triangles")

# %%
# The eigenbasis and the two OFP bases
# ------------------------------------
# :func:`o3d_ofp.eigenbasis` solves for the constant and the first ``k`` non-constant
# eigenfunctions (``k=29``: the paper's K = 30). :func:`o3d_ofp.ofp_basis` multiplies them up to
# order 2 and runs a mass-weighted Gram-Schmidt that drops the products already in the span of
# those kept: preset ``"ours"`` drops those with less than 1 % of their norm left, ``"ours*"``
# keeps every product that is numerically independent.
eig = ofp.eigenbasis(vertices, faces, k=29)
ours = ofp.ofp_basis(eig, order=2, preset="ours")
ours_star = ofp.ofp_basis(eig, order=2, preset="ours*")

approximations = {
    "K eigs": eig.reconstruct(eig.project(colors)),
    "ours": ours.approximate(colors),
    "ours*": ours_star.approximate(colors),
}
sizes = {"K eigs": eig.k + 1, "ours": ours.size, "ours*": ours_star.size}
print("basis    functions  RGB error")
for name, approx in approximations.items():
    error = ofp.approximation_error(colors, approx, eig.mass)
    print(f"{name:8s} {sizes[name]:9d}  {100 * error:8.2f}%")

# %%
# The errors are relative, ``‖f − f̃‖_M / ‖f‖_M`` (:func:`o3d_ofp.approximation_error`): the
# products of 30 eigenfunctions represent the colors much better than the 30 eigenfunctions
# themselves, at the cost of one eigensolve of the same size.
#
# The approximations, rendered headless with Open3D (:func:`o3d_ofp.render_panel` returns the
# picture as an array):
view = View(front=(0.2, -0.4, 1.0), up=(0.0, 1.0, 0.0))
items = [(vertices, faces, colors)]
items += [(vertices, faces, np.clip(a, 0.0, 1.0)) for a in approximations.values()]
titles = ["original"] + [f"{name} ({sizes[name]})" for name in approximations]
panel = ofp.render_panel(items, titles=titles, width=320, height=320, view=view)

fig, ax = plt.subplots(figsize=(10, 3))
ax.imshow(panel)
ax.set_axis_off()
fig.tight_layout()

# %%
# What the basis functions look like
# ----------------------------------
# Every OFP function comes from one eigenproduct (:attr:`o3d_ofp.OFPBasis.products` gives its
# index tuple), in graded-lexicographic order: the constant, the eigenfunctions, then the
# products φᵢφⱼ. A product of two low-frequency eigenfunctions is almost a combination of the
# eigenfunctions already kept, and the "ours" threshold drops it; "ours*" keeps all of them.
candidates = ofp.eigenproduct_indices(eig.k, 2)
products = ours.products
dropped = [p for p in candidates if p not in set(products)]
print(f"{len(candidates)} candidates, {ours.size} kept by 'ours', {ours_star.size} by 'ours*'")
print(f"first products dropped by 'ours': {dropped[:5]}")
print(f"first product kept by 'ours': {products[eig.k + 1]}")

# %%
# Four functions of the "ours" basis: two eigenfunctions and two orthonormalized products.
picks = [1, 2, eig.k + 1, ours.size - 1]
for i in picks:
    print(
        f"basis function {i:3d}: product {products[i]}, "
        f"Dirichlet energy {ours.dirichlet_energies[i]:.1f}"
    )
# each function divided by its largest magnitude, so that all four share one color scale
tiles = [(vertices, faces, ours.Q[:, i] / np.abs(ours.Q[:, i]).max()) for i in picks]
names = [" · ".join(f"φ{j}" for j in products[i]) for i in picks]
panel = ofp.render_panel(
    tiles,
    titles=names,
    width=320,
    height=320,
    view=view,
    cmap="RdBu_r",
    scalar_range=(-1.0, 1.0),
    colorbar_label="value / largest magnitude",
)

fig, ax = plt.subplots(figsize=(10, 3.4))
ax.imshow(panel)
ax.set_axis_off()
fig.tight_layout()
plt.show()
