"""One BLAS thread for the command line, unless the environment says otherwise.

Imported by ``gateway.cli`` before anything loads numpy. The fits' matrices are small (rows x
at most a dozen parameters), so a BLAS thread pool mostly spins: ``discrepancy`` on a
100,000-row record took 36 s of CPU with the default pool and 14.5 s with one thread
(measured on the 2-core machine). Set ``OPENBLAS_NUM_THREADS`` to choose otherwise.
"""

from __future__ import annotations

import os

for _name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")
