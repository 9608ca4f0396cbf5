"""The search kernels: compiled on both cores on a fresh install, loaded before the first frame.

numba compiles one kernel at a time (a global compiler lock), about 3 s for the search's
kernels on a laptop core, after about a second of numba's own start. On a cold cache,
:func:`compile_search_kernels` starts a helper process that compiles the HOG block kernel
(normalising the blocks), the windows' colour scores and the box refinement's colour kernel
into the cache while this process compiles the others: the HOG cells, the colour sums, the
windows' HOG scores and the refinement's HOG part (the search's own functions on a blank band,
its blocks left zero, so with exactly the argument types of a real search); this process then
loads the helper's kernels from the cache. The helper also pays its imports and numba's start,
so it takes the smaller share of the kernels. The kernels are those of the default search
(``window_border="frame"``); a plan with ``"crop"`` compiles its own on first use. No kernel
allocates an array (work arrays are passed in): numba then has no allocation code of its own
to compile first, which is a third of a second. The helper runs a real search on a blank frame
with this process's kernels replaced by no-ops (in the helper only: nothing is replaced here,
so a search running in another thread meanwhile is unaffected). On a machine busy with other
work the two processes share what is free, which is never slower than compiling everything
here (the helper costs its imports, about 0.3 s of CPU). The results never depend on this: a
kernel the helper did not provide in time is compiled here as usual.

The command line starts that helper process earlier still, before it imports anything of the
detector (:func:`start_helper`, for ``detect`` and ``evaluate``): its compile then overlaps this
process's imports and its reading of the inputs (numba's included, about a second), and
:func:`compile_search_kernels` takes it over. A script can do the same before its own imports.

On a warm cache nothing happens here, nor with a single core. Either way the kernels are then
loaded by :func:`load_search_kernels`: a video's run
(:meth:`~vehicle_detection.detector.Detector.steps`) compiles first, in the thread it runs in (so
that Ctrl-C stops the compile and the helper), then loads them in a thread of their own while its
first frames are read and measured.
"""

from __future__ import annotations

import atexit
import hashlib
import importlib
import os
import subprocess
import sys
import threading
from contextlib import contextmanager
from pathlib import Path

from . import _jit  # the cache folder only: numba, NumPy and the search are imported where used

__all__ = ["compile_search_kernels", "load_search_kernels", "start_helper", "stop_helper"]

_DONE = threading.Event()
_LOCK = threading.Lock()
_STARTED: list = []  # the helper process started ahead of the first search (start_helper), if any
_ATEXIT: list = []  # stop_helper registered to run at exit
_LOADED: dict = {}  # (window border, refines or not): set once that search's kernels are loaded
# (module the search calls it through, name, cache file prefix)
_HELPER_KERNELS = (
    ("search", "_block_map", "features._block_map-"),  # defined in features, called through search
    ("search", "_score_colour", "search._score_colour-"),
)
_MAIN_KERNELS = (
    ("search", "_region_cells", "features._region_cells-"),
    ("search", "_colour_sums", "search._colour_sums-"),
    ("search", "_score_blocks", "search._score_blocks-"),
)

# For models that refine their boxes: the HOG part here, the colour part in the helper (a blank
# band scored with every window counted as hot).
_MAIN_REFINE_KERNELS = (
    ("search", "_hog_products_frame", "search._hog_products_frame-"),
)
_HELPER_REFINE_KERNELS = (
    ("search", "_colour_products", "search._colour_products-"),
)


def _module(name: str):
    return importlib.import_module(f"{__package__}.{name}")  # the module, not the package's lazy names


def _cache_folder() -> Path:
    """The folder of the cache where numba keeps this package's kernels.

    numba gives each source folder its own: the folder's name and the SHA-1 of its absolute
    path (numba's ``_CacheLocator.get_suitable_cache_subpath``). Another install of the package
    (another venv, another checkout) has its own.
    """
    source = os.path.dirname(os.path.abspath(__file__))
    return Path(_jit.CACHE_DIR) / f"{os.path.basename(source)}_{hashlib.sha1(source.encode()).hexdigest()}"


def _cached(kernels) -> bool:
    """Whether numba's cache holds an index for every one of ``kernels`` (a warm cache).

    In this very package's folder of the cache (:func:`_cache_folder`), not another install's,
    and for this Python (numba names each index ``module.kernel-line.py311.nbi``). Whether an
    index is current is numba's to decide when it loads it (against a hash of the source, in
    recent versions): after an upgrade the first run may find stale ones and compile here,
    without the helper, once.
    """
    if _jit.CACHE_DIR is None:
        return True  # no cache: nothing to share between processes
    tag = ".py%d%d%s.nbi" % (*sys.version_info[:2], getattr(sys, "abiflags", ""))
    try:
        names = [e.name for e in os.scandir(_cache_folder()) if e.name.endswith(tag)]
    except OSError:
        return False  # no folder yet
    return all(any(name.startswith(prefix) for name in names) for _, _, prefix in kernels)


# Kernels with more than one output (their last arguments); every other kernel's output is its last.
_OUTPUTS = {"_colour_sums": 2}  # bin_means, cell_scores


def _zero_outputs(n: int):
    """A no-op kernel that leaves its ``n`` outputs (its last arguments) zero, not uninitialised.

    An output left as ``np.empty`` gave it may hold NaN, and NaN margins: no window of the
    helper's blank band would then be hot, and the refinement's kernels would not compile.
    """
    def no_op(*args) -> None:
        for out in args[-n:]:
            out.fill(0)
    return no_op


def _cores() -> int:
    """Cores this process may run on."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


@contextmanager
def _without(kernels):
    """Replace ``kernels`` by no-ops that zero their outputs, for the duration (the helper process
    only: never in a user's process)."""
    saved = []
    for mod, fn, _ in kernels:
        m = _module(mod)
        saved.append((m, fn, getattr(m, fn)))
        setattr(m, fn, _zero_outputs(_OUTPUTS.get(fn, 1)))
    try:
        yield
    finally:
        for m, fn, f in saved:
            setattr(m, fn, f)


def _blank_band(model, plan=None):
    """The first band of ``plan`` (default: the model's) in a blank frame, or None."""
    import numpy as np

    from .search import _band, _working_frame

    plan = plan if plan is not None else model.detector_config.plan
    work, _ = _working_frame(np.zeros((720, 320, 3), np.uint8), plan)
    for s in plan.scales:
        band = _band(work, s, model.config, plan.overhang_of(s), plan.y_shift)
        if band is not None:
            return band
    return None


def _compile_main(model) -> None:
    """This process's half: the cells, colour sums and HOG window-score kernels and the
    refinement's HOG part, by the search's own functions with the arguments a search gives them,
    nothing replaced."""
    import numpy as np

    from .search import _band_features, _kernel_weights, _margins, _refine_hog

    band = _blank_band(model)
    if band is None:
        return
    frame = model.detector_config.plan.window_border == "frame"
    feats = _band_features(band, model, lambda name, shape, dtype=np.float64: np.empty(shape, dtype), False, frame)
    if not frame:  # a plan searching crops: its colour scores here too
        _margins(feats, model, band.rows, band.cols)
        return
    # the HOG part of the margins (search._margins); the colour part compiles in the helper
    _module("search")._score_blocks(feats.blocks, _kernel_weights(model).hog, band.rows, band.cols,
                                    np.zeros((len(band.rows), len(band.cols))))
    if model.box_regressor is not None:
        index = np.arange(1)
        _refine_hog(feats, model, band.rows[index // len(band.cols)], band.cols[index % len(band.cols)], np.zeros((1, 4)))


def _all_kernels(refine: bool) -> tuple:
    return _HELPER_KERNELS + _MAIN_KERNELS + (_MAIN_REFINE_KERNELS + _HELPER_REFINE_KERNELS if refine else ())


def _start_process():
    """The helper process, compiling its half into the cache folder; None if it cannot start."""
    env = dict(os.environ)
    env["NUMBA_CACHE_DIR"] = str(_jit.CACHE_DIR)
    # this very package, not another install, by the path numba keys its cache on (not resolved:
    # through a symlinked folder the helper would compile into another folder of the cache)
    package_parent = str(Path(os.path.abspath(__file__)).parents[1])
    env["PYTHONPATH"] = os.pathsep.join([package_parent] + [p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p])
    try:
        return subprocess.Popen(
            # its kernels are in the cache once _helper returns: it exits at once (no teardown, a
            # third of a second that this process would wait for)
            [sys.executable, "-c", "import os; from vehicle_detection.warmup import _helper; _helper(); os._exit(0)"],
            env=env, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        )
    except OSError:
        return None  # compiled here on first use


def _end(helper) -> None:
    if helper.poll() is None:
        helper.kill()
        helper.wait()


def start_helper() -> None:
    """Start the helper process now, ahead of the first search, where
    :func:`compile_search_kernels` would start it (a cold cache, two cores).

    Its compile then overlaps this process's own imports and reading of its inputs: the command
    line starts it before it imports the command it runs (about a second, numba's included).
    Nothing here imports numba, NumPy or the search. :func:`compile_search_kernels` takes the
    process over; :func:`stop_helper` ends one that no search took over, as the interpreter's
    exit does. The results never depend on this.
    """
    with _LOCK:
        # a model without the refinement never compiles its kernels: the cache is warm without them
        if _DONE.is_set() or _STARTED or _cores() < 2 or _cached(_all_kernels(refine=False)):
            return
        helper = _start_process()
        if helper is not None:
            if not _ATEXIT:
                atexit.register(stop_helper)  # a script that never searches leaves no helper behind
                _ATEXIT.append(True)
            _STARTED.append(helper)


def stop_helper() -> None:
    """End the helper process :func:`start_helper` started, if no search took it over (a command
    that failed before its first search, for one)."""
    with _LOCK:
        while _STARTED:
            _end(_STARTED.pop())


def compile_search_kernels(model) -> None:
    """Before the first search of a run: on a cold cache, compile the kernels in two processes.

    The helper process is the one :func:`start_helper` started, else one started now. Later
    calls return at once; nothing of this process is replaced, so any thread may search meanwhile.
    """
    with _LOCK:
        if _DONE.is_set():
            return
        _DONE.set()
        helper = _STARTED.pop() if _STARTED else None
        if _cores() < 2 or _cached(_all_kernels(model.box_regressor is not None)):
            if helper is not None:
                _end(helper)
            return
        helper = helper or _start_process()
        if helper is None:
            return  # compiled here on first use
        try:
            _compile_main(model)
            helper.wait(timeout=60)
        except subprocess.TimeoutExpired:
            pass
        finally:
            _end(helper)


def load_search_kernels(model, plan=None) -> None:
    """Load every kernel of a search into this process: from the cache, else compiled.

    A blank band is scored with every window counted as hot, by the search's own code path, so
    that the kernels the first frame needs are ready. Loading them from a warm cache also starts
    numba (its registries; not SciPy's linear algebra, see :mod:`~vehicle_detection._jit`): a
    third of a second of one core or more, mostly in Python, which
    :meth:`~vehicle_detection.detector.Detector.steps` runs in a thread (after
    :func:`compile_search_kernels`) while the first frames are read and measured. A call
    while another thread loads them waits for it; later calls for the same kind of search return
    at once. The results never depend on this: a kernel not loaded here is compiled on first use.

    Parameters
    ----------
    model : VehicleClassifier
    plan : SearchPlan, optional
        The plan searched with (default: the model's); its ``window_border`` decides the kernels.
    """
    import numpy as np

    from .search import _score_band

    plan = plan if plan is not None else model.detector_config.plan
    key = (plan.window_border, model.box_regressor is not None)
    with _LOCK:  # held by compile_search_kernels while it compiles
        loaded = _LOADED.get(key)
        first = loaded is None
        if first:
            loaded = _LOADED[key] = threading.Event()
    if not first:
        loaded.wait()  # another thread is loading them: ready when it is done
        return
    try:
        band = _blank_band(model, plan)
        if band is not None:
            _score_band(band, model, reuse=False, refine_above=-np.inf, frame=plan.window_border == "frame")
    finally:
        loaded.set()


def _helper() -> None:
    """The helper process's half: a real search of a blank frame with the main half's kernels as
    no-ops, and its first band scored with every window counted as hot (the refinement's kernels)."""
    import numpy as np

    from .classifier import load_default_model
    from .search import _score_band, search

    model = load_default_model()
    with _without(_MAIN_KERNELS + _MAIN_REFINE_KERNELS):  # this process only
        search(np.zeros((720, 320, 3), np.uint8), model)
        band = _blank_band(model)
        if band is not None and model.box_regressor is not None:
            _score_band(band, model, reuse=False, refine_above=-np.inf, frame=model.detector_config.plan.window_border == "frame")
