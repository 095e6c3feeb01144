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
from .laplacian import laplacian
from .orthogonalize import PRESETS, GramSchmidt, gram_schmidt
from .products import eigenproduct_indices, eigenproducts, n_eigenproducts
from .spectrum import EigenBasis, EigenSolverError, eigenbasis

__version__ = "0.1.0"

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
    "gram_schmidt",
    "laplacian",
    "n_eigenproducts",
    "ofp_basis",
]

logging.getLogger(__name__).addHandler(logging.NullHandler())
