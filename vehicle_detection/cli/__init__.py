"""The ``vehicle-detection`` command line: :func:`main` (the console script) and its parser.

``python -m vehicle_detection.cli ...`` runs it too.
"""

import os

# The command line runs threads of its own (search, decoding, encoding) and, for batches, processes:
# a BLAS thread pool would only compete with them, and its threads spin for a while after the
# library loads (about a tenth of a second of a core, for NumPy's and again for SciPy's, which
# numba imports). So the BLAS libraries start with one thread, unless the user says otherwise;
# this must come before NumPy is imported. Detection uses no BLAS call on a hot path.
for _name in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

from .main import main  # noqa: E402
from .parser import build_parser  # noqa: E402

__all__ = ["main", "build_parser"]
