"""Compare the CLI's memory estimate (core._memory.basis_job_bytes) with measured peaks.

For each shape and (k, order): the estimate, the peak NumPy/SciPy allocation seen by
tracemalloc, and the growth of the process's peak resident memory (ru_maxrss, which also
sees the C allocations of the sparse factorization) over the baseline after reading the mesh;
each case runs in a fresh process so peaks do not carry over. Prints one row per case and
the load average.

    nice python scripts/bench_memory_estimate.py [MESH ...]
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

CHILD = r"""
import json, resource, sys, tracemalloc
import numpy as np
import o3d_ofp as ofp
from o3d_ofp.core.shapes import blob
path, k, order = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
if path.startswith("blob"):
    V, F = blob(int(path[4:]))
else:
    from o3d_ofp.boundary.convert import geometry_to_arrays
    V, F = geometry_to_arrays(ofp.read_geometry(path))
base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
tracemalloc.start()
B = ofp.ofp_basis(ofp.eigenbasis(V, F, k=k), order=order)
traced = tracemalloc.get_traced_memory()[1]
tracemalloc.stop()
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
print(json.dumps({"n": int(V.shape[0]), "traced": traced, "rss_growth": peak - base,
                  "size": int(B.size)}))
"""


def main(argv: list[str]) -> int:
    """Run the cases and print the table."""
    from o3d_ofp.core._memory import basis_job_bytes, format_bytes

    meshes = argv or ["blob4", "blob5"]
    cases = [(m, k, o) for m in meshes for k, o in ((29, 2), (29, 3))]
    print(f"load average before: {open('/proc/loadavg').read().split()[:3]}")
    print(f"{'shape':<40} {'n':>7} {'k':>3} {'N':>2} {'estimate':>10} {'traced':>10} "
          f"{'rss growth':>10} {'est/rss':>7}")  # fmt: skip
    for mesh, k, order in cases:
        out = subprocess.run(
            [sys.executable, "-c", CHILD, mesh, str(k), str(order)],
            capture_output=True, text=True, check=True, env={**os.environ, "OMP_NUM_THREADS": "1"},
        )  # fmt: skip
        r = json.loads(out.stdout.strip().splitlines()[-1])
        est = basis_job_bytes(r["n"], k=k, order=order)
        ratio = est / max(r["rss_growth"], 1)
        print(f"{os.path.basename(mesh):<40} {r['n']:>7} {k:>3} {order:>2} "
              f"{format_bytes(est):>10} {format_bytes(r['traced']):>10} "
              f"{format_bytes(r['rss_growth']):>10} {ratio:>7.2f}")  # fmt: skip
    print(f"load average after: {open('/proc/loadavg').read().split()[:3]}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
