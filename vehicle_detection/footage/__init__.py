"""Reading the footage: where its horizon is, how dark it is, where it cuts between shots, and its bars and overlays.

What a video or picture is like before the search looks at it: measured on its first frames (and
again at each cut), it moves the search bands, brightens dark frames, resets the tracker, and
keeps the search off the black bars and the camera car's own parts. The five stages
(features, classifier, search, heat map, tracker) read these measures; none of them is a stage.

The names are loaded on first use (the stub ``__init__.pyi`` lists them).
"""

import lazy_loader as _lazy

__getattr__, __dir__, __all__ = _lazy.attach_stub(__name__, __file__)
