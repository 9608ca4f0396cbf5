"""Where compiled kernels are cached: never inside the package (read-only installs, leftovers)."""

import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

import vehicle_detection

PACKAGE = Path(vehicle_detection.__file__).parent
#: Compiles (or loads) a parallel kernel of the package and checks its numbers: 6 s of CPU to compile.
SCRIPT = (
    "import numpy as np\n"
    "from vehicle_detection import _jit\n"
    "from vehicle_detection.features import bin_spatial\n"
    "out = bin_spatial(np.full((64, 64, 3), 7, np.uint8), 16)\n"
    "assert out.shape == (768,) and float(out[0]) == 7.0, out[:3]\n"
    "print(_jit.CACHE_DIR)\n"
)
#: The same with a small plain kernel (L2-Hys of four ones: all 0.5, within fastmath's rounding), 1.5 s of CPU: enough where
#: only the cache's folder is in question (the parallel kernel's caching is checked above).
SMALL_SCRIPT = (
    "import numpy as np\n"
    "from vehicle_detection import _jit\n"
    "from vehicle_detection.features import _l2hys\n"
    "out = np.ones(4)\n"
    "_l2hys(out)\n"
    "assert np.allclose(out, 0.5, rtol=1e-6, atol=0), out\n"  # fastmath: within rounding
    "print(_jit.CACHE_DIR)\n"
)


def _run(tmp_path, script=SMALL_SCRIPT, **env_overrides):
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    env.update(env_overrides)
    proc = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return proc.stdout.strip().splitlines()[-1]


def _new_index_files(folder: Path, since: float) -> list[Path]:
    return [p for p in folder.rglob("*.nbi") if p.stat().st_mtime >= since]


def test_cache_goes_to_the_user_cache_folder(tmp_path):
    start = time.time() - 1
    cache_home = tmp_path / "cache"
    where = _run(tmp_path, SCRIPT, XDG_CACHE_HOME=str(cache_home))  # the default: a parallel kernel
    assert Path(where) == cache_home / "vehicle-detection" / "numba"
    assert _new_index_files(cache_home, start), "no kernel was cached in the user cache folder"
    assert not _new_index_files(PACKAGE, start), "a kernel cache was written inside the package"


def test_user_setting_is_respected(tmp_path):
    where = _run(tmp_path, NUMBA_CACHE_DIR=str(tmp_path / "mine"))
    assert Path(where) == tmp_path / "mine"
    assert list((tmp_path / "mine").rglob("*.nbi"))


def test_unwritable_cache_falls_back_to_the_temporary_folder(tmp_path):
    blocker = tmp_path / "a-file"
    blocker.write_text("not a folder")
    (tmp_path / "tmp").mkdir()
    # The user cache folder cannot be created (its parent is a file, which stops root too).
    where = _run(tmp_path, XDG_CACHE_HOME=str(blocker / "cache"), TMPDIR=str(tmp_path / "tmp"))
    assert Path(where).parent == tmp_path / "tmp"


def test_nothing_writable_compiles_without_a_cache(tmp_path):
    blocker = tmp_path / "a-file"
    blocker.write_text("not a folder")
    # A user-set folder that cannot be created, and nothing else tried: the kernels still
    # compile and compute the same numbers (checked by the script), uncached.
    assert _run(tmp_path, NUMBA_CACHE_DIR=str(blocker / "numba")) == "None"


def test_install_that_cannot_be_written_runs_help_and_detect(tmp_path):
    """A copy of the package that is never written to, and no writable cache folder anywhere:
    ``--help`` and ``detect`` work, and the install is left byte for byte as it was."""
    import shutil

    site = tmp_path / "site"
    shutil.copytree(PACKAGE, site / "vehicle_detection", ignore=shutil.ignore_patterns("__pycache__"))
    before = {p: p.stat().st_mtime_ns for p in site.rglob("*")}
    blocker = tmp_path / "a-file"
    blocker.write_text("not a folder")
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    env.update(
        PYTHONPATH=str(site), PYTHONDONTWRITEBYTECODE="1", NUMBA_CACHE_DIR=str(blocker / "numba"),
        XDG_CACHE_HOME=str(blocker / "cache"), TMPDIR=str(blocker / "tmp"),
    )
    video = PACKAGE.parent / "test_video.mp4"  # committed
    help_run = subprocess.run([sys.executable, "-m", "vehicle_detection.cli", "--help"], env=env, capture_output=True,
                              text=True, timeout=300, cwd=tmp_path)
    assert help_run.returncode == 0 and "detect" in help_run.stdout, help_run.stderr[-2000:]
    out = tmp_path / "out"
    out.mkdir()
    # Four frames: the kernels are compiled (uncached) all the same, and a car is tracked. The same run shows
    # that compiling every kernel of the search imports no scipy.linalg (loading them: the next test).
    argv = ["detect", str(video), "--no-video", "--out-dir", str(out), "--no-progress", "--frames", "0-3"]
    script = (
        "import sys\n"
        "from vehicle_detection.cli.main import main\n"
        f"code = main({argv!r})\n"
        "print(code, 'scipy.linalg' in sys.modules)\n"
    )
    run = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=600, cwd=tmp_path)
    assert run.returncode == 0, run.stderr[-2000:]
    assert run.stdout.strip().splitlines()[-1] == "0 False"  # exit code 0, no scipy.linalg
    assert (out / "test_video_boxes.csv").read_text().count("\n") > 1
    assert {p: p.stat().st_mtime_ns for p in site.rglob("*")} == before  # nothing written, nothing added


def test_kernels_run_without_scipy_linalg_and_numba_finds_blas_as_it_would(tmp_path, numba_as_it_comes):
    # The search's kernels are loaded without importing scipy.linalg (compiled: the test above); numba's BLAS
    # check says what numba's own import says, and a kernel of the user's that takes BLAS
    # (np.correlate of floats) still gets it, with NumPy's result.
    script = (
        "import sys, threading\n"
        "import numpy as np\n"
        "import vehicle_detection as vd\n"
        "from vehicle_detection import _jit\n"
        "image = np.zeros((720, 1280, 3), np.uint8)\n"
        "vd.Detector().detect_image(image)\n"
        "from numba.np import arraymath\n"
        "print('scipy.linalg' in sys.modules, arraymath._HAVE_BLAS)\n"
        "print(any(isinstance(f, _jit._NoLinalg) for f in sys.meta_path))\n"
        "from numba import njit\n"
        "got = njit(lambda a, b: np.correlate(a, b))(np.arange(5.0), np.array([1.0, 2.0]))\n"
        "print(np.array_equal(got, np.correlate(np.arange(5.0), np.array([1.0, 2.0]))), 'scipy.linalg' in sys.modules)\n"
        "finder, seen = _jit._NoLinalg(), []\n"
        "other = threading.Thread(target=lambda: seen.append(finder.find_spec('scipy.linalg')))\n"
        "other.start()\n"
        "other.join()\n"
        "try:\n"
        "    finder.find_spec('scipy.linalg')\n"
        "except ImportError:\n"
        "    seen.append('refused here')\n"
        "print(seen)\n"
    )
    # The cache this test run uses: warm once any run has searched (a cold one compiles, with the helper, as before).
    from vehicle_detection import _jit

    env = {**os.environ, "NUMBA_CACHE_DIR": str(_jit.CACHE_DIR or tmp_path / "cache")}
    proc = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    lines = proc.stdout.split("\n")
    assert lines[0] == f"False {numba_as_it_comes.split()[1]}"  # no scipy.linalg; numba's own answer
    assert lines[1] == "False"  # the finder is gone
    assert lines[2] == "True True"  # the user's BLAS kernel: NumPy's result, scipy.linalg imported for it
    assert lines[3] == "[None, 'refused here']"  # refused only to the importing thread


#: Imports the package's kernels with ``{check}`` as the BLAS check the hook looks for; prints whether
#: scipy.linalg was imported, and numba's BLAS answer.
BLAS_SCRIPT = (
    "import sys\n"
    "from vehicle_detection import _jit\n"
    "_jit._BLAS_CHECK = {check!r}\n"
    "import vehicle_detection.features\n"
    "from numba.np import arraymath\n"
    "print('scipy.linalg' in sys.modules, arraymath._HAVE_BLAS)\n"
)


def _blas_run(check: str) -> str:
    proc = subprocess.run([sys.executable, "-c", BLAS_SCRIPT.format(check=check)], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return proc.stdout.strip()


@pytest.fixture(scope="module")
def numba_as_it_comes() -> str:
    """A check the hook does not know: the hook stands aside, numba imports its arraymath itself (scipy.linalg
    with it) and gives its own BLAS answer, as in a process without the package (the other test of BLAS compares
    with it)."""
    return _blas_run("_HAVE_BLAS = _another_check()")


def test_a_numba_that_checks_blas_otherwise_imports_as_it_comes(numba_as_it_comes):
    # The hook is used only where numba's module holds the check it was written for.
    assert [_blas_run("_HAVE_BLAS = _check_blas()"), numba_as_it_comes] == ["False True", "True True"]
