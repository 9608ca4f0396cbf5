"""Scoring against hand-labelled frames: detection and tracking scores, the runner over labelled
footage, and the per-camera report.

The names are loaded on first use (the stub ``__init__.pyi`` lists them).
"""

import lazy_loader as _lazy

__getattr__, __dir__, __all__ = _lazy.attach_stub(__name__, __file__)
