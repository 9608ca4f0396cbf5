"""Cold-start kernel compilation on two cores: safe no-ops around it."""

from __future__ import annotations

import importlib
from pathlib import Path

import numpy as np

from vehicle_detection import _warmup

features = importlib.import_module("vehicle_detection.features")
search = importlib.import_module("vehicle_detection.search")


def test_without_restores_the_kernels_and_zeroes_outputs():
    before = (search._region_cells, search._score_blocks, search._block_map, search._colour_sums, search._score_colour)
    with _warmup._without(_warmup._HELPER_KERNELS + _warmup._MAIN_KERNELS):
        assert search._region_cells is _warmup._zero_last
        out = np.ones(3)
        search._score_blocks(1, 2, out)
        assert not out.any()
    assert (search._region_cells, search._score_blocks, search._block_map, search._colour_sums, search._score_colour) == before


def test_every_kernel_is_compiled_by_one_side():
    names = {fn for _, fn, _ in _warmup._HELPER_KERNELS + _warmup._MAIN_KERNELS}
    assert names == {"_region_cells", "_colour_sums", "_score_colour", "_score_blocks", "_block_map"}
    for mod, fn, prefix in _warmup._HELPER_KERNELS + _warmup._MAIN_KERNELS:
        assert hasattr(_warmup._module(mod), fn) and prefix.endswith(fn + "-")


def test_searching_after_the_warm_up_gives_the_same_windows(default_model, test_frames):
    before = search.search(test_frames[0], default_model)
    _warmup._DONE.clear()
    _warmup.compile_search_kernels(default_model)  # warm cache here: nothing to do
    after = search.search(test_frames[0], default_model)
    np.testing.assert_array_equal(before.xyxy, after.xyxy)
    np.testing.assert_array_equal(before.score, after.score)



def test_a_search_compiles_each_kernel_for_one_signature():
    """A strided view or another dtype would make numba compile a kernel again (seconds of a cold start)."""
    import subprocess
    import sys

    code = (
        "import numpy as np, vehicle_detection as vd\n"
        "from vehicle_detection import search as S, features as F\n"
        "from vehicle_detection.io.images import read_image\n"
        "d = vd.Detector()\n"
        "for name in ('test1.jpg', 'test4.jpg'):\n"
        "    S.search(read_image('test_images/' + name), d.model)\n"
        "kernels = [S._score_blocks, S._score_colour, S._colour_sums, S._hog_products_frame, S._colour_products,\n"
        "           S._region_cells, S._block_map]\n"
        "print([len(k.signatures) for k in kernels])\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         cwd=Path(__file__).resolve().parents[1])
    assert out.stdout.strip() == "[1, 1, 1, 1, 1, 1, 1]", out.stdout + out.stderr
