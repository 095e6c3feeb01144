"""
Colors onto a point cloud
=========================

Every function of the package takes point clouds as well as meshes: their Laplacian is
robust-laplacian's point-cloud one, built from each point's neighbours. Here the colors of a
mesh go to a point cloud, a bent copy of the mesh's vertices in a random order, through a
map that :func:`o3d_ofp.match` estimates between the mesh and the cloud.
"""

# %%
# A mesh and a cloud
# ------------------
# The source is a colored blob mesh. The target is an :class:`open3d.geometry.PointCloud`
# made of the blob's vertices, bent (``y += 0.15 x²``) and shuffled: it has no triangles, and
# ``true_source[j]`` is the source vertex point ``j`` came from.
import matplotlib.pyplot as plt
import numpy as np
import open3d as o3d

import o3d_ofp as ofp
from o3d_ofp.core.shapes import blob
from o3d_ofp.render import View
from o3d_ofp.workflows.demo import demo_signal

vertices, faces = blob(4)  # 2562 vertices
colors = demo_signal(vertices)  # the demo's pattern: smooth bands, sharp stripes
source = o3d.geometry.TriangleMesh(
    o3d.utility.Vector3dVector(vertices), o3d.utility.Vector3iVector(faces)
)
source.vertex_colors = o3d.utility.Vector3dVector(colors)

bent = vertices.copy()
bent[:, 1] += 0.15 * bent[:, 0] ** 2
true_source = np.random.default_rng(0).permutation(len(vertices))
cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(bent[true_source]))

# %%
# The map
# -------
# For a point cloud the quality report counts reversed *neighbourhoods* (the share of the
# cloud's neighbourhoods where the map is a reflection) instead of reversed triangles.
corr = ofp.match(source, cloud)
print(corr.quality.summary())
root_area = np.sqrt(ofp.eigenbasis(source, k=1).area)
error = np.linalg.norm(vertices[corr.p2p_21] - vertices[true_source], axis=1).mean()
print(f"map error: {error / root_area:.4f} (mean distance / sqrt(area), against the truth)")

# %%
# The transfer
# ------------
# :func:`o3d_ofp.transfer_colors` returns a new point cloud with the colors (the input cloud
# is not modified). The error is measured against the source colors at the true points, with
# the cloud's own mass (the area each point stands for).
colored = ofp.transfer_colors(source, cloud, correspondence=corr)
transferred = np.asarray(colored.colors)
cloud_eig = ofp.eigenbasis(cloud, k=1)
print(f"RGB error: {ofp.approximation_error(colors[true_source], transferred, cloud_eig.mass):.2%}")
print(f"input cloud still without colors: {not cloud.has_colors()}")

# %%
# The source mesh, the colored cloud, and the cloud colored with the truth:
points = np.asarray(cloud.points)
panel = ofp.render_panel(
    [(vertices, faces, colors), (points, None, transferred), (points, None, colors[true_source])],
    titles=["source mesh", "cloud, transferred", "cloud, truth"],
    width=320,
    height=320,
    view=View(front=(0.2, -0.4, 1.0)),
    point_size=10,
)
fig, ax = plt.subplots(figsize=(9, 3.4))
ax.imshow(panel)
ax.set_axis_off()
fig.tight_layout()
plt.show()
