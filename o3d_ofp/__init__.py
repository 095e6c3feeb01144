"""o3d_ofp: Orthogonalized Fourier Polynomials for Open3D meshes and point clouds.

Importing this package does not import Open3D; only :mod:`o3d_ofp.adapters` does, lazily.

References
----------
.. [1] G. Maggioli, S. Melzi, M. Bronstein, M. Ovsjanikov, E. Rodolà, "Orthogonalized Fourier
   Polynomials for Signal Approximation and Transfer", Computer Graphics Forum 40(2), 2021
   (Eurographics 2021). doi:10.1111/cgf.142645
"""

from __future__ import annotations

import logging

from .basis import OFPBasis, approximation_error, ofp_basis
from .cache import cached_basis
from .cleaning import CleaningReport, clean_shape
from .correspondence import fmap_from_p2p, nearest_neighbors, p2p_from_fmap, p2p_from_template
from .descriptors import hks, wks
from .fmap import estimate_fmap, icp_refine, lift_fmap, zoomout_refine
from .laplacian import laplacian
from .orthogonalize import PRESETS, GramSchmidt, gram_schmidt
from .pipeline import match, transfer_function
from .products import eigenproduct_indices, eigenproducts, n_eigenproducts
from .render import render_panel, show
from .spectrum import EigenBasis, EigenSolverError, eigenbasis, shape_digest
from .transfer import transfer_matrix, transfer_signal

__version__ = "0.1.0"


def _open3d_level(name: str):
    """Make a package-level alias of an :mod:`o3d_ofp.adapters` function (lazy import)."""

    def call(*args, **kwargs):
        from . import adapters

        return getattr(adapters, name)(*args, **kwargs)

    call.__name__ = call.__qualname__ = name
    call.__doc__ = f"Open3D level; see :func:`o3d_ofp.adapters.{name}`."
    return call


transfer_colors = _open3d_level("transfer_colors")
transfer_detail = _open3d_level("transfer_detail")
filter_geometry = _open3d_level("filter_geometry")
texture_colors = _open3d_level("texture_colors")
read_geometry = _open3d_level("read_geometry")
write_geometry = _open3d_level("write_geometry")

__all__ = [
    "PRESETS",
    "CleaningReport",
    "EigenBasis",
    "EigenSolverError",
    "GramSchmidt",
    "OFPBasis",
    "__version__",
    "approximation_error",
    "cached_basis",
    "clean_shape",
    "eigenbasis",
    "eigenproduct_indices",
    "eigenproducts",
    "estimate_fmap",
    "filter_geometry",
    "fmap_from_p2p",
    "gram_schmidt",
    "hks",
    "icp_refine",
    "laplacian",
    "lift_fmap",
    "match",
    "n_eigenproducts",
    "nearest_neighbors",
    "ofp_basis",
    "p2p_from_fmap",
    "p2p_from_template",
    "read_geometry",
    "render_panel",
    "shape_digest",
    "show",
    "texture_colors",
    "transfer_colors",
    "transfer_detail",
    "transfer_function",
    "transfer_matrix",
    "transfer_signal",
    "wks",
    "write_geometry",
    "zoomout_refine",
]

logging.getLogger(__name__).addHandler(logging.NullHandler())
