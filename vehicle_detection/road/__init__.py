"""The road around the detections: the camera's lens, the road plane, lanes, and distances.

The names are loaded on first use (the stub ``__init__.pyi`` lists them).
"""

import lazy_loader as _lazy

__getattr__, __dir__, __all__ = _lazy.attach_stub(__name__, __file__)
