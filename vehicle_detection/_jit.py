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
"""

from __future__ import annotations

import os
import sys
import tempfile
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


def njit(**options):
    """``numba.njit`` with ``cache=True`` where a cache folder is writable.

    numba is imported here, on the first kernel defined, not with this module: the helper
    process of :mod:`~vehicle_detection.warmup` is started from the cache folder alone,
    before the command line's imports.
    """
    import numba

    if CACHE_DIR is not None:
        numba.config.CACHE_DIR = str(CACHE_DIR)  # numba may have been imported before us
    return numba.njit(cache=CACHE_DIR is not None, **options)
