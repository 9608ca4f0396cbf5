"""Whole runs: a video through the detector (:func:`process_video`), one input of any kind with
every option (:func:`run_input`), many inputs at once (:func:`detect_many`), and live frames.

The names are loaded on first use (the stub ``__init__.pyi`` lists them).
"""

import lazy_loader as _lazy

__getattr__, __dir__, __all__ = _lazy.attach_stub(__name__, __file__)
