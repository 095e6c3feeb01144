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
from .correspondence import fmap_from_p2p, nearest_neighbors, p2p_from_fmap
from .descriptors import hks, wks
from .fmap import estimate_fmap, icp_refine, lift_fmap, zoomout_refine
from .laplacian import laplacian
from .orthogonalize import PRESETS, GramSchmidt, gram_schmidt
from .products import eigenproduct_indices, eigenproducts, n_eigenproducts
from .spectrum import EigenBasis, EigenSolverError, eigenbasis
from .transfer import transfer_matrix, transfer_signal

__version__ = "0.1.0"


def transfer_colors(source, target, **options):  # noqa: D103 - documented in adapters
    from .adapters import transfer_colors as impl

    return impl(source, target, **options)


def transfer_detail(source, target, **options):  # noqa: D103 - documented in adapters
    from .adapters import transfer_detail as impl

    return impl(source, target, **options)


transfer_colors.__doc__ = "Open3D level; see :func:`o3d_ofp.adapters.transfer_colors`."
transfer_detail.__doc__ = "Open3D level; see :func:`o3d_ofp.adapters.transfer_detail`."

__all__ = [
    "PRESETS",
    "EigenBasis",
    "EigenSolverError",
    "GramSchmidt",
    "OFPBasis",
    "__version__",
    "approximation_error",
    "eigenbasis",
    "eigenproduct_indices",
    "eigenproducts",
    "estimate_fmap",
    "fmap_from_p2p",
    "gram_schmidt",
    "hks",
    "icp_refine",
    "laplacian",
    "lift_fmap",
    "n_eigenproducts",
    "nearest_neighbors",
    "ofp_basis",
    "p2p_from_fmap",
    "transfer_colors",
    "transfer_detail",
    "transfer_matrix",
    "transfer_signal",
    "wks",
    "zoomout_refine",
]

logging.getLogger(__name__).addHandler(logging.NullHandler())
