"""vehicle-detection: find and track vehicles in dashcam video with HOG features and a linear SVM.

The public API is loaded lazily: ``import vehicle_detection as vd`` is fast, and each name
imports its module on first use. The stub ``__init__.pyi`` lists the names (type checkers and
IDEs read it; :func:`lazy_loader.attach_stub` reads it at run time): the core's, and each
subpackage's (``vd.io``, ``vd.footage``, ``vd.road``, ``vd.metrics``, ``vd.training``, ``vd.viz``,
``vd.pipeline``), whose own stubs list their names.

>>> import vehicle_detection as vd
>>> detector = vd.Detector()                                    # the embedded model
>>> found = detector.detect_image(vd.read_image("test_images/test1.jpg"))
>>> type(found).__name__, found.xyxy.shape[1]
('Detections', 4)
"""

import lazy_loader as _lazy

from . import deprecation

__version__ = "0.2.0"

__getattr__, __dir__, __all__ = _lazy.attach_stub(__name__, __file__)
__all__ = ["__version__", *__all__]

deprecation.install()  # the earlier module paths (vehicle_detection.batch, ...) still import, with a warning
