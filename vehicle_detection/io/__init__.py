"""Reading and writing: images, video, the boxes tables and their formats, and safe output files.

Every output goes through :func:`atomic_output` (never a half-written file under its final name,
never an input overwritten); :func:`output_batch` commits a run's outputs together. The names
are loaded on first use (the stub ``__init__.pyi`` lists them).
"""

import lazy_loader as _lazy

__getattr__, __dir__, __all__ = _lazy.attach_stub(__name__, __file__)
