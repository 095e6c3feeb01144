"""Collections of shapes: one source onto many targets, the bases of many shapes, on Dask.

:func:`~o3d_ofp.transfer_many` transfers a source's vertex colors, texture or detail onto every
target, each target a task on a Dask cluster (a local one sized to the machine by default),
the source's bases computed once and shared; :func:`~o3d_ofp.bases_many` fills a basis cache for a
whole collection; :func:`~o3d_ofp.write_summary` writes a run's records as ``summary.csv`` and
``summary.json``.

Importing this package does not import Dask (``pip install 'o3d_ofp[dask]'``): it is imported
when a cluster is used.

Notes
-----
Thread safety: the library's calls may run concurrently in threads of one process (a Dask
worker with several threads): their results are those of the same calls made one after the
other (tested), up to round-off where BLAS ran on a different number of threads. The BLAS
thread limits the core sets around its iterative stages are process-wide; they are kept in
one record shared by all threads (``o3d_ofp.core._threads.blas_threads``), so interleaved
calls neither lift each other's limit nor leave it behind. Workers with several threads
still share those limits and the cores, so the local cluster runs one single-threaded worker
process per core.
"""

from __future__ import annotations

from .engine import (
    BLAS_ENV,
    COUNTERS,
    MESH_EXTENSIONS,
    bases_many,
    expand_paths,
    local_workers,
    open_client,
    transfer_many,
)
from .results import SUMMARY_FIELDS, TargetResult, write_summary

__all__ = [
    "BLAS_ENV",
    "COUNTERS",
    "MESH_EXTENSIONS",
    "SUMMARY_FIELDS",
    "TargetResult",
    "bases_many",
    "expand_paths",
    "local_workers",
    "open_client",
    "transfer_many",
    "write_summary",
]
