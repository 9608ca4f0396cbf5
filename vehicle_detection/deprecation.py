"""The module paths that moved when the package was laid out in subpackages, kept working for one
release with a warning.

``import vehicle_detection.batch`` (or ``from vehicle_detection.evaluate import ...``) still works:
the old module path is answered by a stand-in module that hands every name on from the new
module, and importing it emits a :class:`DeprecationWarning` naming the new path. Names that
moved out of a module that stays (``vehicle_detection.classifier.train``) are handed on by that
module's ``__getattr__``, with the same warning. Everything here goes in the next release.

The tables below are the whole list; ``tests/test_layers.py`` checks that every entry resolves.
"""

from __future__ import annotations

import functools
import importlib
import importlib.abc
import importlib.machinery
import sys
import types
import warnings
from collections.abc import Callable

__all__ = ["MOVED_MODULES", "MOVED_NAMES", "install", "moved_attribute", "old_keywords"]

_P = "vehicle_detection"

#: Old module path -> new module path.
MOVED_MODULES: dict[str, str] = {
    f"{_P}.{old}": f"{_P}.{new}"
    for old, new in {
        "_files": "io._files",
        "images": "io.images",
        "video": "io.video",
        "tables": "io.tables",
        "formats": "io.formats",
        "data": "training.data",
        "download": "training.download",
        "mining": "training.mining",
        "camera": "road.camera",
        "lanes": "road.lanes",
        "evaluate": "metrics.detection",
        "tracking_metrics": "metrics.tracking",
        "reporting": "metrics.reporting",
        "drawing": "viz.drawing",
        "plots": "viz.plots",
        "batch": "pipeline.batch",
        "live": "pipeline.live",
        # the modules that read the footage, gathered in footage/
        "horizon": "footage.horizon",
        "exposure": "footage.exposure",
        "shots": "footage.shots",
        "overlays": "footage.overlays",
    }.items()
}

#: Module path (old or staying) -> {name that moved out of it: its new module}.
MOVED_NAMES: dict[str, dict[str, str]] = {
    f"{_P}.classifier": {
        name: f"{_P}.training.fit" for name in ("train", "sweep", "sweep_configs", "split_indices", "with_box_refinement")
    },
    f"{_P}.lanes": {"DistanceTracker": f"{_P}.road.distance"},
    f"{_P}.formats": {name: f"{_P}.detections" for name in ("to_supervision", "from_supervision")},
    f"{_P}.batch": {
        name: f"{_P}.pipeline.inputs"
        for name in ("FORMATS", "VIDEO_EXTENSIONS", "default_outputs", "expand_inputs", "input_kind", "unknown_type")
    },
}


def _warn(old: str, new: str, stacklevel: int) -> None:
    warnings.warn(f"{old} is deprecated and will be removed in the next release; use {new}", DeprecationWarning,
                  stacklevel=stacklevel + 1)


def moved_attribute(module: str, name: str):
    """``name`` of ``module`` that moved elsewhere (with a warning); AttributeError if it did not."""
    new = MOVED_NAMES.get(module, {}).get(name)
    if new is None:
        raise AttributeError(f"module {module!r} has no attribute {name!r}")
    _warn(f"{module}.{name}", f"{new}.{name}", stacklevel=3)  # the caller of the module's __getattr__
    return getattr(importlib.import_module(new), name)


class _StandIn(types.ModuleType):
    """An old module path: every name is looked up in the new module (or where it moved)."""

    def __getattr__(self, name: str):
        if name.startswith("__"):
            raise AttributeError(name)
        moved = MOVED_NAMES.get(self.__name__, {})
        if name in moved:
            return getattr(importlib.import_module(moved[name]), name)
        return getattr(importlib.import_module(MOVED_MODULES[self.__name__]), name)

    def __dir__(self) -> list[str]:
        new = importlib.import_module(MOVED_MODULES[self.__name__])
        return sorted(set(dir(new)) | set(MOVED_NAMES.get(self.__name__, {})))


class _Finder(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Answers the old module paths with stand-ins."""

    def find_spec(self, fullname, path=None, target=None):
        if fullname not in MOVED_MODULES:
            return None
        return importlib.machinery.ModuleSpec(fullname, self)

    def create_module(self, spec):
        _warn(spec.name, MOVED_MODULES[spec.name], stacklevel=2)  # the import (importlib's frames are skipped)
        return _StandIn(spec.name, f"Moved to {MOVED_MODULES[spec.name]}.")

    def exec_module(self, module) -> None:
        pass


def install() -> None:
    """Answer the old module paths (once per process), before any other finder: a file of the
    old layout left on the path (an older install) must not answer them."""
    if not any(isinstance(f, _Finder) for f in sys.meta_path):
        sys.meta_path.insert(0, _Finder())


def old_keywords(names: tuple[str, ...], convert: Callable[[dict], dict]):
    """A decorator: the function still takes its earlier keyword arguments ``names``, with a warning.

    ``convert`` turns the call's keyword arguments (old ones included) into new ones; the
    function's own signature lists only the new ones.
    """

    def decorate(func):
        @functools.wraps(func)
        def wrapper(*args, **kwargs):
            old = sorted(set(kwargs) & set(names))
            if old:
                warnings.warn(
                    f"{func.__qualname__}({', '.join(f'{n}=' for n in old)}) is deprecated and will be removed in the "
                    f"next release; see help({func.__module__}.{func.__qualname__})", DeprecationWarning, stacklevel=2,
                )
                kwargs = convert(kwargs)
            return func(*args, **kwargs)

        return wrapper

    return decorate
