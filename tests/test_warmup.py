"""Cold-start kernel compilation on two cores: safe no-ops around it."""

from __future__ import annotations

import importlib
from pathlib import Path

import numpy as np
import pytest

from vehicle_detection import warmup

features = importlib.import_module("vehicle_detection.features")
search = importlib.import_module("vehicle_detection.search")


def test_without_restores_the_kernels_and_zeroes_outputs():
    before = (search._region_cells, search._score_blocks, search._block_map, search._colour_sums, search._score_colour)
    with warmup._without(warmup._HELPER_KERNELS + warmup._MAIN_KERNELS):
        assert search._region_cells is not before[0]
        out = np.ones(3)
        search._score_blocks(1, 2, out)
        assert not out.any()
        bin_means, cell_scores = np.full(4, np.nan), np.full(2, np.nan)
        search._colour_sums(1, 2, 3, 4, bin_means, cell_scores)  # two outputs
        assert not bin_means.any() and not cell_scores.any()
    assert (search._region_cells, search._score_blocks, search._block_map, search._colour_sums, search._score_colour) == before


def test_every_kernel_is_compiled_by_one_side():
    kernels = (warmup._HELPER_KERNELS + warmup._MAIN_KERNELS + warmup._MAIN_REFINE_KERNELS
               + warmup._HELPER_REFINE_KERNELS)
    names = [fn for _, fn, _ in kernels]
    assert sorted(names) == sorted({"_region_cells", "_colour_sums", "_score_colour", "_score_blocks", "_block_map",
                                    "_hog_products_frame", "_colour_products"})
    for mod, fn, prefix in kernels:
        assert hasattr(warmup._module(mod), fn) and prefix.endswith(fn + "-")


def test_the_helpers_blank_band_is_hot_whatever_its_buffers_held(default_model):
    """The helper's no-ops leave every output zero: with buffers full of NaN (what ``np.empty``
    may give), each window's margin is still a number, so every window is hot and the
    refinement's kernels compile (NaN margins once left ``_colour_products`` to the main process)."""
    band = warmup._blank_band(default_model)

    def garbage(name, shape, dtype=np.float64):
        return np.full(shape, np.nan, dtype) if np.issubdtype(dtype, np.floating) else np.full(shape, 7, dtype)

    with warmup._without(warmup._MAIN_KERNELS + warmup._MAIN_REFINE_KERNELS):
        feats = search._band_features(band, default_model, garbage, True, True)
        margins = search._margins(feats, default_model, band.rows, band.cols)
    assert margins.size and np.isfinite(margins).all()


def _compiled_in_a_fresh_cache(tmp_path, code: str) -> tuple[set, set]:
    """Run ``code`` in a new process with an empty numba cache: the kernels it compiled itself
    (numba's compile events) and the cache index files it left."""
    import os
    import subprocess
    import sys

    script = (
        "from numba.core import event\n"
        "class Seen(event.Listener):\n"
        "    names = set()\n"
        "    def on_start(self, ev): pass\n"
        "    def on_end(self, ev):\n"
        "        f = ev.data['dispatcher'].py_func\n"
        "        if f.__module__.startswith('vehicle_detection'): self.names.add(f.__name__)\n"
        "seen = Seen()\n"
        "event.register('numba:compile', seen)\n"
        + code +
        "print(' '.join(sorted(seen.names)))\n"
    )
    cache = tmp_path / "cache"
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache)}
    proc = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=300,
                          cwd=Path(__file__).resolve().parents[1])
    assert proc.returncode == 0, proc.stderr[-2000:]
    files = {p.name.split("-")[0] for p in cache.rglob("*.nbi")}
    return set(proc.stdout.split()), files


@pytest.fixture(scope="module")
def helper_half(tmp_path_factory):
    """The helper's half run alone in a fresh cache: (kernels it compiled, index files, the cache)."""
    tmp_path = tmp_path_factory.mktemp("helper_half")
    compiled, files = _compiled_in_a_fresh_cache(tmp_path, "from vehicle_detection.warmup import _helper\n_helper()\n")
    return compiled, files, tmp_path / "cache"


@pytest.fixture(scope="module")
def main_half(tmp_path_factory):
    """The main process's half run alone in another fresh cache: (kernels it compiled, index files, the cache)."""
    tmp_path = tmp_path_factory.mktemp("main_half")
    compiled, files = _compiled_in_a_fresh_cache(
        tmp_path, "from vehicle_detection import warmup, load_default_model\nwarmup._compile_main(load_default_model())\n")
    return compiled, files, tmp_path / "cache"


#: The tests of the two halves' runs: one worker makes each run once.
halves_group = pytest.mark.xdist_group(name="warmup-halves")


@halves_group
def test_the_helper_fills_a_fresh_cache_with_its_kernels_only(helper_half):
    """Its search of a blank frame with the main half's kernels as no-ops must run through (each
    no-op zeroes its kernel's output, the last argument) and compile exactly its share."""
    compiled, files, _ = helper_half
    helper = {fn for _, fn, _ in warmup._HELPER_KERNELS + warmup._HELPER_REFINE_KERNELS}
    assert compiled == helper | {"_l2hys"}  # _block_map's normalisation, a kernel of its own
    assert {f.split(".")[1] for f in files} == helper | {"_l2hys"}


@halves_group
def test_the_main_half_compiles_the_other_kernels(main_half):
    compiled, _, _ = main_half
    assert compiled == {fn for _, fn, _ in warmup._MAIN_KERNELS + warmup._MAIN_REFINE_KERNELS}


@halves_group
def test_a_cache_is_warm_only_with_indexes_of_this_install_and_python(tmp_path, monkeypatch, helper_half, main_half):
    # numba's own cache, filled by both halves (each half's files, from its own run above, put in
    # one cache: a kernel is a file of its own): warm, also once the sources are touched (numba
    # checks their content). The same files for another Python, or in another install's folder: cold.
    import os
    import shutil
    import sys

    for _, _, cache in (helper_half, main_half):
        shutil.copytree(cache, tmp_path / "cache", dirs_exist_ok=True)
    monkeypatch.setattr(warmup._jit, "CACHE_DIR", tmp_path / "cache")
    kernels = warmup._all_kernels(refine=True)
    folder = warmup._cache_folder()
    assert folder.is_dir() and warmup._cached(kernels)
    index = next(folder.glob("search._score_blocks-*.nbi"))
    old = (Path(warmup.__file__).parent / "search.py").stat().st_mtime - 60
    os.utime(index, (old, old))  # written before the source's last change: numba still loads it
    assert warmup._cached(kernels)
    index.rename(index.with_name(index.name.replace(".py%d%d" % sys.version_info[:2], ".py27")))
    assert not warmup._cached(kernels)
    assert warmup._cached(warmup._HELPER_KERNELS)  # the others are there
    shutil.move(folder, folder.with_name("vehicle_detection_" + "0" * 40))  # another install's
    assert not warmup._cached(warmup._HELPER_KERNELS)


def test_searching_after_the_warm_up_gives_the_same_windows(default_model, test_frames):
    before = search.search(test_frames[0], default_model)
    warmup._DONE.clear()
    warmup.compile_search_kernels(default_model)  # warm cache here: nothing to do
    after = search.search(test_frames[0], default_model)
    np.testing.assert_array_equal(before.xyxy, after.xyxy)
    np.testing.assert_array_equal(before.score, after.score)




def test_loading_the_kernels_leaves_nothing_for_the_first_frame_to_compile(tmp_path):
    """``load_search_kernels`` runs the search's own path on a blank band with every window hot:
    in a fresh cache it compiles every kernel a search of a real frame with cars needs, so that
    search compiles none (a kernel it missed would be compiled on the first frame, not meanwhile).
    Each kernel has one signature after searches of two frames: a strided view or another dtype would
    make numba compile a kernel again (seconds of a cold start)."""
    code = (
        "from vehicle_detection import warmup, load_default_model\n"
        "from vehicle_detection.io.images import read_image\n"
        "import vehicle_detection.search as S\n"
        "m = load_default_model()\n"
        "warmup.load_search_kernels(m)\n"
        "print('loaded:' + ','.join(sorted(seen.names)))\n"
        "seen.names.clear()\n"
        "for name in ('test1.jpg', 'test4.jpg'):\n"
        "    found = S.search(read_image('test_images/' + name), m)\n"
        "    assert len(found), name + ' has cars'\n"
        "kernels = [S._score_blocks, S._score_colour, S._colour_sums, S._hog_products_frame, S._colour_products,\n"
        "           S._region_cells, S._block_map]\n"
        "print('signatures:' + ','.join(str(len(k.signatures)) for k in kernels))\n"
    )
    compiled, _ = _compiled_in_a_fresh_cache(tmp_path, code)
    loaded = next(w for w in compiled if w.startswith("loaded:"))
    every = {fn for _, fn, _ in warmup._HELPER_KERNELS + warmup._MAIN_KERNELS + warmup._MAIN_REFINE_KERNELS
             + warmup._HELPER_REFINE_KERNELS}
    assert set(loaded.removeprefix("loaded:").split(",")) >= every
    assert "signatures:1,1,1,1,1,1,1" in compiled  # one signature each
    assert compiled == {loaded, "signatures:1,1,1,1,1,1,1"}  # the real frames' searches compiled nothing


def test_a_second_caller_waits_for_the_kernels_being_loaded(default_model, monkeypatch):
    """Two threads ask at once: the second waits, and returns only when the first has loaded them."""
    import threading
    from types import SimpleNamespace

    started, release, waiting, order = threading.Event(), threading.Event(), threading.Event(), []

    class Spy(threading.Event):
        def wait(self, timeout=None):
            waiting.set()  # the second caller is about to wait
            return super().wait(timeout)

    def slow_score(*args, **kwargs):
        started.set()
        release.wait(10)
        order.append("loaded")

    monkeypatch.setattr(search, "_score_band", slow_score)  # imported by the loader when it runs
    monkeypatch.setattr(warmup, "_LOADED", {})
    monkeypatch.setattr(warmup, "threading", SimpleNamespace(Event=Spy))
    first = threading.Thread(target=warmup.load_search_kernels, args=(default_model,))
    second = threading.Thread(target=lambda: (warmup.load_search_kernels(default_model), order.append("second")))
    try:
        first.start()
        assert started.wait(10)
        second.start()
        assert waiting.wait(10)  # the second caller waits on the first's event
        assert order == []
    finally:
        release.set()
        first.join(10)
        second.join(10)
    assert order == ["loaded", "second"]
    warmup.load_search_kernels(default_model)  # loaded: at once, nothing scored again
    assert order == ["loaded", "second"]


def test_a_run_that_fails_while_the_kernels_load_does_not_wait_for_them(default_model, test_frames, monkeypatch):
    """The kernels load in a daemon thread while the first frames are measured: when the
    measurement fails (a damaged video, Ctrl-C), the error reaches the caller at once, so its
    clean-up runs, while the loading goes on (or is abandoned at exit)."""
    import threading
    import time

    from vehicle_detection import detector as D

    release, loading = threading.Event(), threading.Event()

    def slow_load(model, plan=None):
        loading.set()
        release.wait(30)

    def damaged(self, frames, tracker, *, workers=1):
        assert loading.wait(10)  # the loader is busy now
        raise RuntimeError("damaged video")

    monkeypatch.setattr(D, "compile_search_kernels", lambda model: None)
    monkeypatch.setattr(D, "load_search_kernels", slow_load)
    monkeypatch.setattr(D.Detector, "for_footage", damaged)
    det = D.Detector(default_model)
    start = time.perf_counter()
    try:
        with pytest.raises(RuntimeError, match="damaged video"):
            next(det.steps(iter(test_frames), det.new_tracker(), 1))
        assert time.perf_counter() - start < 5  # not the loader's 30 s
    finally:
        release.set()


class _FakeHelper:
    """A helper process that never runs: what start_helper / compile_search_kernels do with it."""

    started: list = []

    def __init__(self):
        self.killed = self.waited = False
        _FakeHelper.started.append(self)

    def poll(self):
        return 0 if self.killed or self.waited else None

    def kill(self):
        self.killed = True

    def wait(self, timeout=None):
        self.waited = True
        return 0


def _cold(monkeypatch):
    _FakeHelper.started = []
    monkeypatch.setattr(warmup, "_DONE", __import__("threading").Event())
    monkeypatch.setattr(warmup, "_STARTED", [])
    monkeypatch.setattr(warmup, "_ATEXIT", [True])  # no stop_helper left registered by these tests
    monkeypatch.setattr(warmup, "_cores", lambda: 2)
    monkeypatch.setattr(warmup, "_cached", lambda kernels: False)
    monkeypatch.setattr(warmup, "_start_process", _FakeHelper)
    monkeypatch.setattr(warmup, "_compile_main", lambda model: None)


def test_a_helper_started_early_is_taken_over_by_the_first_search(default_model, monkeypatch):
    _cold(monkeypatch)
    warmup.start_helper()
    warmup.start_helper()  # once
    assert len(_FakeHelper.started) == 1
    warmup.compile_search_kernels(default_model)
    assert len(_FakeHelper.started) == 1 and _FakeHelper.started[0].waited  # no second process
    warmup.stop_helper()
    assert not _FakeHelper.started[0].killed  # it was the search's to end


def test_a_helper_no_search_took_over_is_stopped(monkeypatch):
    _cold(monkeypatch)
    warmup.start_helper()
    warmup.stop_helper()
    assert _FakeHelper.started[0].killed and warmup._STARTED == []


def test_no_helper_on_a_warm_cache_or_one_core(monkeypatch):
    _cold(monkeypatch)
    monkeypatch.setattr(warmup, "_cached", lambda kernels: True)
    warmup.start_helper()
    monkeypatch.setattr(warmup, "_cached", lambda kernels: False)
    monkeypatch.setattr(warmup, "_cores", lambda: 1)
    warmup.start_helper()
    assert _FakeHelper.started == []


def test_a_warm_cache_ends_a_helper_started_early(default_model, monkeypatch):
    _cold(monkeypatch)
    warmup.start_helper()
    monkeypatch.setattr(warmup, "_cached", lambda kernels: True)  # the kernels were cached meanwhile
    warmup.compile_search_kernels(default_model)
    assert _FakeHelper.started[0].killed and warmup._STARTED == []


def test_the_first_helper_registers_its_end_at_exit(monkeypatch):
    _cold(monkeypatch)
    monkeypatch.setattr(warmup, "_ATEXIT", [])
    registered = []
    monkeypatch.setattr(warmup.atexit, "register", registered.append)
    warmup.start_helper()
    warmup.stop_helper()
    warmup.start_helper()
    assert registered == [warmup.stop_helper]


def test_the_helper_started_early_compiles_its_half_without_numba_numpy_or_the_search_here(tmp_path):
    """A real helper process in a fresh cache, started as the command line starts it: this process
    imports nothing heavy, the helper exits cleanly and leaves exactly its kernels in the cache."""
    import os
    import subprocess
    import sys

    code = ("import sys, vehicle_detection.warmup as w\n"
            "w.start_helper()\n"
            "rc = w._STARTED[0].wait(240)\n"
            "print(rc, sorted(m for m in ('numba', 'numpy', 'vehicle_detection.search') if m in sys.modules))\n")
    cache = tmp_path / "cache"
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300,
                          env={**os.environ, "NUMBA_CACHE_DIR": str(cache)}, cwd=Path(__file__).resolve().parents[1])
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.split(maxsplit=1) == ["0", "[]\n"]
    helper = {fn for _, fn, _ in warmup._HELPER_KERNELS + warmup._HELPER_REFINE_KERNELS}
    assert {f.name.split("-")[0].split(".")[1] for f in cache.rglob("*.nbi")} == helper | {"_l2hys"}
