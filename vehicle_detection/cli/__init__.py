"""The ``vehicle-detection`` command line: :func:`main` (the console script) and its parser.

``python -m vehicle_detection.cli ...`` runs it too.
"""

from .main import main
from .parser import build_parser

__all__ = ["main", "build_parser"]
