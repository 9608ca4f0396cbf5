"""The ``vehicle-detection`` command line: :func:`main`, :func:`run` (the console script) and its parser.

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

from .main import main, run  # noqa: E402  (light: a command's modules are imported when it runs)

__all__ = ["main", "run", "build_parser"]


def __getattr__(name: str):
    if name == "build_parser":  # the parser imports the features' defaults, and with them numba
        from .parser import build_parser

        return build_parser
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
