"""Compiled kernels: numba's ``njit`` with the on-disk cache in a per-user folder.

numba caches compiled kernels beside the source file by default, that is inside the installed
package. That fails on a read-only install (a system-wide one, a service user, a read-only
container) and leaves a ``__pycache__`` folder behind in ``site-packages`` that outlives the
package and shadows a later editable install. The cache goes instead to the first writable of

1. ``$NUMBA_CACHE_DIR`` when the user set it (numba's own setting, respected as it is);
2. the per-user cache folder: ``$XDG_CACHE_HOME`` or ``~/.cache`` (``~/Library/Caches`` on macOS,
   ``%LOCALAPPDATA%`` on Windows), then ``vehicle-detection/numba``;
3. ``vehicle-detection-numba-<user>`` in the system temporary folder.

When none is writable the kernels are compiled on every run, without a cache (slower to start,
the same results).

numba checks a cached kernel against its own source file only, not against the files of the
kernels it calls (``search._score_hog`` calls ``features._clipped_block``, for one). An install
or upgrade writes every file anew, so nothing stale is loaded; a developer who edits a kernel in
one file that another file's kernel calls must clear the cache folder (:data:`CACHE_DIR`).

numba's module of NumPy array functions, which the first kernel compiled or loaded imports,
checks at import whether SciPy's BLAS is there (for ``np.correlate`` and ``np.convolve``) by
importing ``scipy.linalg``: 0.2 to 0.3 s of every run's start, in the main process and in the
helper of :mod:`~vehicle_detection.warmup`, for a check that no kernel here depends on. It is
imported with the first kernel defined, ``scipy.linalg`` out of its reach while it is (in this
thread only), and the check's answer is then set from whether SciPy is installed, as the
package requires it to be (a kernel that uses BLAS imports ``scipy.linalg`` when it is compiled,
as ever, and fails there if SciPy's BLAS does not suit numba).
"""

from __future__ import annotations

import importlib.abc
import importlib.util
import os
import sys
import tempfile
import threading
from pathlib import Path

__all__ = ["CACHE_DIR", "njit"]


def _user_cache_home() -> Path:
    if sys.platform == "win32":
        return Path(os.environ.get("LOCALAPPDATA") or Path.home() / "AppData" / "Local")
    if sys.platform == "darwin":
        return Path.home() / "Library" / "Caches"
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")


def _writable(folder: Path) -> bool:
    try:
        folder.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=folder):
            pass
    except OSError:
        return False
    return True


def _candidates() -> list[Path]:
    if os.environ.get("NUMBA_CACHE_DIR"):
        return [Path(os.environ["NUMBA_CACHE_DIR"])]
    out = []
    try:
        out.append(_user_cache_home() / "vehicle-detection" / "numba")
    except RuntimeError:  # no home folder
        pass
    user = os.environ.get("USER") or os.environ.get("USERNAME") or str(getattr(os, "getuid", lambda: "user")())
    out.append(Path(tempfile.gettempdir()) / f"vehicle-detection-numba-{user}")
    return out


def _choose_cache_dir() -> Path | None:
    return next((c for c in _candidates() if _writable(c)), None)


#: Where compiled kernels are cached, or None when no folder is writable (no cache).
CACHE_DIR: Path | None = _choose_cache_dir()

if CACHE_DIR is not None:
    os.environ["NUMBA_CACHE_DIR"] = str(CACHE_DIR)  # numba reads it on import


class _NoLinalg(importlib.abc.MetaPathFinder):
    """Refuses ``scipy.linalg`` to the thread that installed it (:func:`_import_arraymath`)."""

    def __init__(self) -> None:
        self.thread = threading.get_ident()

    def find_spec(self, name, path=None, target=None):
        if name == "scipy.linalg" and threading.get_ident() == self.thread:
            raise ImportError("scipy.linalg: not imported for numba's BLAS check (vehicle_detection._jit)")
        return None


#: The line of ``numba.np.arraymath`` that imports ``scipy.linalg`` (through ``ensure_blas``).
_BLAS_CHECK = "_HAVE_BLAS = _check_blas()"


def _import_arraymath() -> None:
    """Import ``numba.np.arraymath`` without ``scipy.linalg`` (see the module's notes).

    Only where the module checks for BLAS as the numba versions this was written for do: a
    numba that imports ``scipy.linalg`` otherwise imports it as it comes (a module whose import
    failed half-way would register its functions twice when imported again).
    """
    if "numba.np.arraymath" in sys.modules or "scipy.linalg" in sys.modules:
        return  # done already, or the check is cheap
    try:
        spec = importlib.util.find_spec("numba.np.arraymath")
        source = Path(spec.origin).read_text(encoding="utf-8")
    except (ImportError, AttributeError, TypeError, OSError, ValueError):
        return
    if source.count(_BLAS_CHECK) != 1 or "scipy" in source:
        return  # not the check this expects, or a module that imports SciPy itself
    finder = _NoLinalg()
    sys.meta_path.insert(0, finder)
    try:
        from numba.np import arraymath
    except ImportError:
        return  # another numba: imported as it comes, by the first kernel
    finally:
        sys.meta_path.remove(finder)
    arraymath._HAVE_BLAS = importlib.util.find_spec("scipy") is not None  # SciPy installed, not imported


def njit(**options):
    """``numba.njit`` with ``cache=True`` where a cache folder is writable.

    numba is imported here, on the first kernel defined, not with this module: the helper
    process of :mod:`~vehicle_detection.warmup` is started from the cache folder alone,
    before the command line's imports.
    """
    import numba

    _import_arraymath()
    if CACHE_DIR is not None:
        numba.config.CACHE_DIR = str(CACHE_DIR)  # numba may have been imported before us
    return numba.njit(cache=CACHE_DIR is not None, **options)
