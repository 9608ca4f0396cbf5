"""Sliding-window search: plan validation, the plain path, and fast == plain on real frames."""

from __future__ import annotations

import numpy as np
import pytest

from reference_search import classify_windows, search_plain, slide_window
from vehicle_detection.search import SearchPlan, SearchScale, plan_windows, search


def test_slide_window_counts_and_geometry():
    wins = slide_window((720, 1280, 3), x_start_stop=(0, 256), y_start_stop=(400, 528), xy_window=(64, 64), xy_overlap=(0.5, 0.5))
    # 32-pixel steps: x in 0..192 (7 positions), y in 400..464 (3 positions)
    assert wins.shape == (21, 4)
    assert set(wins[:, 0]) == set(range(0, 193, 32))
    assert set(wins[:, 1]) == {400, 432, 464}
    assert np.all(wins[:, 2] - wins[:, 0] == 64) and np.all(wins[:, 3] - wins[:, 1] == 64)
    assert wins[:, 2].max() <= 256 and wins[:, 3].max() <= 528


def test_slide_window_rejects_full_overlap():
    with pytest.raises(ValueError):
        slide_window((100, 100), xy_overlap=(1.0, 0.5))


@pytest.mark.parametrize(
    "kwargs",
    [dict(scale=0, y_start=0, y_stop=10), dict(scale=1, y_start=10, y_stop=10), dict(scale=1, y_start=0, y_stop=10, step=0),
     dict(scale=1, y_start=0, y_stop=10, x_start=50, x_stop=40)],
)
def test_search_scale_validation(kwargs):
    with pytest.raises(ValueError):
        SearchScale(**kwargs)


def test_plan_round_trip():
    plan = SearchPlan()
    assert SearchPlan.from_dict(plan.to_dict()) == plan
    with pytest.raises(ValueError):
        SearchPlan(scales=())


def test_plan_windows_match_search_boxes(default_model):
    frame = np.zeros((720, 1280, 3), np.uint8)
    per_scale = plan_windows(frame.shape, SearchPlan(), default_model.config)
    wins = search(frame, default_model, all_windows=True)
    assert np.array_equal(np.concatenate(per_scale), wins.xyxy)
    for k, s in enumerate(SearchPlan().scales):
        b = per_scale[k]
        assert len(b) > 0
        side = round(64 * s.scale)
        inside = (b[:, 0] > 0) & (b[:, 2] < 1280)  # windows overhanging an edge are clipped
        assert np.all(np.abs((b[inside, 2] - b[inside, 0]) - side) <= 1)
        if SearchPlan().overhang_of(s):  # windows overhang both edges
            assert b[:, 0].min() == 0 and b[:, 2].max() == 1280 and (~inside).sum() >= 2
        else:  # small windows stay inside the frame
            assert b[:, 0].min() == 0 and 1280 - side < b[:, 2].max() <= 1280 and np.all(np.abs(b[:, 2] - b[:, 0] - side) <= 1)
        assert b[:, 1].min() >= s.y_start and b[:, 3].max() <= s.y_stop
        assert b[:, 0].min() >= 0 and b[:, 2].max() <= 1280


# One frame a window border: a second frame with the same border runs the same code (test5 with
# "frame" was dropped: the plain reference takes seconds a frame).
@pytest.mark.parametrize(("index", "border"), [(0, "frame"), (3, "crop")])
def test_fast_and_plain_paths_agree_on_real_frames(default_model, test_frames, index, border):
    from dataclasses import replace

    frame = test_frames[index]
    plan = replace(default_model.detector_config.plan, window_border=border)
    fast = search(frame, default_model, plan, all_windows=True)
    plain = search_plain(frame, default_model, plan)
    assert len(fast) == len(plain) > 1000
    assert np.array_equal(fast.xyxy, plain.xyxy)
    assert np.array_equal(fast.data["scale_index"], plain.data["scale_index"])
    # Same margins to rounding error (float32 cells: 1e-5), hence the same decision on every
    # window not on the fence.
    tol = 1e-6 if border == "crop" else 1e-5
    np.testing.assert_allclose(fast.score, plain.score, rtol=0, atol=tol)
    clear = np.abs(plain.score) > tol
    assert np.array_equal(fast.score[clear] > 0, plain.score[clear] > 0)
    assert (plain.score > 0).any() and (plain.score < 0).any()


def test_the_window_border_changes_only_the_border_cells(default_model, test_frames):
    """Seen across their border, windows score close to their crops (the same cells inside)."""
    from dataclasses import replace

    plan = default_model.detector_config.plan
    frame_b = search(test_frames[0], default_model, replace(plan, window_border="frame"), all_windows=True)
    crop_b = search(test_frames[0], default_model, replace(plan, window_border="crop"), all_windows=True)
    assert np.array_equal(frame_b.xyxy, crop_b.xyxy)
    assert 0.99 < np.corrcoef(frame_b.score, crop_b.score)[0, 1] < 1 - 1e-9
    assert np.abs(frame_b.score - crop_b.score).max() > 1e-3


def test_plans_saved_before_the_window_border_search_their_windows_as_crops():
    plan = SearchPlan()
    assert plan.window_border == "frame"
    old = {k: v for k, v in plan.to_dict().items() if k != "window_border"}
    assert SearchPlan.from_dict(old).window_border == "crop"
    assert SearchPlan.from_dict(SearchPlan(window_border="crop").to_dict()).window_border == "crop"
    with pytest.raises(ValueError, match="window_border"):
        SearchPlan(window_border="zero")


def test_search_threshold_filters(default_model, test_frames):
    frame = test_frames[0]
    all_w = search(frame, default_model, all_windows=True)
    hot = search(frame, default_model, SearchPlan(threshold=0.5))
    assert np.array_equal(np.sort(hot.score), np.sort(all_w.score[all_w.score > 0.5]))


def test_classify_windows_resizes_to_patch(default_model, test_frames):
    frame = test_frames[0]
    wins = np.array([[800, 400, 960, 560], [0, 0, 64, 64]])
    scores = classify_windows(frame, wins, default_model)
    import cv2

    patch = cv2.resize(frame[400:560, 800:960], (64, 64), interpolation=cv2.INTER_AREA)
    assert scores.shape == (2,)
    assert scores[0] == pytest.approx(default_model.decision_images(patch[None])[0])
    assert scores[1] == pytest.approx(default_model.decision_images(frame[None, 0:64, 0:64])[0])


def test_other_frame_sizes_map_back(default_model, test_frames):
    """A half-size frame is searched at the reference height; boxes come back in its pixels."""
    import cv2

    frame = test_frames[0]
    small = cv2.resize(frame, (640, 360), interpolation=cv2.INTER_AREA)
    wins = search(small, default_model, all_windows=True)
    assert wins.xyxy[:, 2].max() <= 640 and wins.xyxy[:, 3].max() <= 360
    big = search(frame, default_model, all_windows=True)
    assert len(wins) == len(big)
    np.testing.assert_allclose(wins.xyxy * 2, big.xyxy, atol=2)


def test_band_outside_frame_is_skipped(default_model):
    plan = SearchPlan(scales=(SearchScale(1.0, 400, 496), SearchScale(1.0, 2000, 2100)))
    wins = search(np.zeros((720, 1280, 3), np.uint8), default_model, plan, all_windows=True)
    assert len(wins) > 0 and np.all(wins.data["scale_index"] == 0)


def test_search_refuses_float_frames(default_model):
    from vehicle_detection.errors import InputError

    with pytest.raises(InputError, match="0-1 versus 0-255"):
        search(np.zeros((720, 1280, 3), np.float32), default_model)


def test_a_changed_model_changes_the_scores(default_model, test_frames):
    """Models are immutable; a changed copy is a new model, and the fast path follows it."""
    frame = test_frames[0]
    with pytest.raises(ValueError, match="read-only"):
        default_model.coef[0] = 1.0
    before = search(frame, default_model, all_windows=True)
    shifted = default_model.replace(intercept=default_model.intercept + 1.0)
    after = search(frame, shifted, all_windows=True)
    assert len(after) > 1000
    np.testing.assert_allclose(after.score - before.score, 1.0, atol=1e-9)
    # The plain reference agrees with the changed model's fast path (on one band of the plan: the
    # reference on the whole plan is test_fast_and_plain_paths_agree_on_real_frames's, seconds).
    band = SearchPlan(scales=(default_model.detector_config.plan.scales[0],))
    np.testing.assert_allclose(search_plain(frame, shifted, band).score, search(frame, shifted, band, all_windows=True).score, atol=1e-5)  # float32 cells


def test_search_uses_the_models_plan_by_default(default_model, test_frames):
    plan = SearchPlan(scales=(SearchScale(1.5, 400, 544),), threshold=-100.0)
    model = default_model.replace(detector_config=default_model.detector_config.replace(plan=plan))
    wins = search(test_frames[0], model)
    assert np.all(wins.data["scale_index"] == 0)
    assert len(wins) == len(search(test_frames[0], model, plan, all_windows=True))


def test_windows_overhang_the_frame_edges(default_model, test_frames):
    """With overhang, windows reach past the left and right edges (mirrored pixels there), and
    come back clipped to the frame; without, none touches an edge they cannot fit at."""
    frame = test_frames[0]
    plan = SearchPlan(scales=(SearchScale(2.0, 400, 592),), overhang=0.5)
    wins = search(frame, default_model, plan, all_windows=True)
    flat = search(frame, default_model, plan.__class__(scales=plan.scales, overhang=0.0), all_windows=True)
    assert len(wins) > len(flat)
    widths = wins.xyxy[:, 2] - wins.xyxy[:, 0]
    assert widths.min() <= 64 + 8 and widths.max() == 128  # half a 128 px window cut off at most
    assert wins.xyxy[:, 0].min() == 0 and wins.xyxy[:, 2].max() == frame.shape[1]
    np.testing.assert_allclose(search_plain(frame, default_model, plan).score, wins.score, atol=1e-5)  # float32 cells


def test_horizon_moves_every_band_together(default_model):
    plan = SearchPlan(scales=(SearchScale(1.0, 400, 496), SearchScale(2.0, 420, 592)), overhang=0.0)
    frame = np.zeros((720, 1280, 3), np.uint8)
    base = np.concatenate(plan_windows(frame.shape, plan, default_model.config))
    # A horizon 0.05 of the height (36 rows at 720) above the reference camera's.
    higher = SearchPlan(scales=plan.scales, overhang=0.0, horizon=plan.reference_horizon - 0.05)
    assert higher.y_shift == -36
    moved = np.concatenate(plan_windows(frame.shape, higher, default_model.config))
    np.testing.assert_array_equal(moved, base + [0, -36, 0, -36])
    assert SearchPlan.from_dict(higher.to_dict()) == higher
    assert SearchPlan(horizon=SearchPlan().reference_horizon).y_shift == 0
    assert SearchPlan(horizon=0.683, reference_horizon=0.583).y_shift == 72
    for field in ("horizon", "reference_horizon"):
        with pytest.raises(ValueError, match=field):
            SearchPlan(**{field: 1.2})
    old = higher.to_dict()
    del old["reference_horizon"]  # plans saved before it: the project camera's
    assert SearchPlan.from_dict(old).reference_horizon == 0.583


def test_plain_python_kernels_compute_the_same(default_model, test_frames, tmp_path):
    """With NUMBA_DISABLE_JIT=1 the kernels run as plain Python (NumPy 2 integer rules): the
    same margins, and the same features."""
    import os
    import subprocess
    import sys

    from vehicle_detection.features import extract_features

    frame = np.ascontiguousarray(test_frames[0][380:580, 800:1120])
    np.save(tmp_path / "frame.npy", frame)
    # Two rows of 9 windows (18): plain Python takes a second of CPU per 30 windows and border.
    plan = SearchPlan(scales=(SearchScale(1.0, 0, 80, x_stop=192),), reference_height=200, overhang=0.0)
    script = (
        "import sys, numpy as np, vehicle_detection as vd\n"
        "from vehicle_detection.search import SearchPlan, search\n"
        f"plan = SearchPlan.from_dict({plan.to_dict()!r})\n"
        "frame = np.load(sys.argv[1])\n"
        "np.save(sys.argv[2], search(frame, vd.load_default_model(), plan, all_windows=True).score)\n"
        "np.save(sys.argv[3], vd.extract_features(frame[None, :64, :64], vd.load_default_model().config))\n"
        "crop = SearchPlan.from_dict({**plan.to_dict(), 'window_border': 'crop'})\n"
        "np.save(sys.argv[4], search(frame, vd.load_default_model(), crop, all_windows=True).score)\n"
    )
    env = {**os.environ, "NUMBA_DISABLE_JIT": "1"}
    out = [tmp_path / "scores.npy", tmp_path / "features.npy", tmp_path / "crop_scores.npy"]
    proc = subprocess.run([sys.executable, "-c", script, str(tmp_path / "frame.npy"), *map(str, out)], env=env,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    jit = search(frame, default_model, plan, all_windows=True).score
    assert len(jit) > 10
    np.testing.assert_allclose(np.load(out[0]), jit, atol=1e-5)
    np.testing.assert_allclose(np.load(out[1]), extract_features(frame[None, :64, :64], default_model.config), atol=1e-5)
    crop = search(frame, default_model, SearchPlan.from_dict({**plan.to_dict(), "window_border": "crop"}), all_windows=True).score
    np.testing.assert_allclose(np.load(out[2]), crop, atol=1e-5)


def test_integer_scales_are_resized_by_whole_pixels():
    """With windows overhanging the frame edges, an integer scale's band is padded to a whole
    number of scaled pixels (OpenCV's block-mean resize), at most ``scale - 1`` pixels short of
    the overhang asked for; other scales keep their padding."""
    from vehicle_detection.features import FeatureConfig
    from vehicle_detection.search import _band

    cfg = FeatureConfig()
    for width in (1280, 1279, 1000, 853):
        frame = np.zeros((720, width, 3), np.uint8)
        for scale in (1.0, 1.5, 2.0, 3.0):
            band = _band(frame, SearchScale(scale, 400, 688), cfg, overhang=0.5)
            pad = round(0.5 * 64 * scale)
            padded = round(band.sx * band.image.shape[1])
            assert width + 2 * pad - scale < padded <= width + 2 * pad
            if scale == int(scale):
                assert band.sx == scale and padded % int(scale) == 0
            assert band.x0 == -pad  # the left edge keeps the overhang asked for


def test_plans_saved_before_the_two_stage_search_score_every_window():
    plan = SearchPlan()
    assert plan.coarse_margin is not None
    old = {k: v for k, v in plan.to_dict().items() if k != "coarse_margin"}
    assert SearchPlan.from_dict(old).coarse_margin is None
    assert SearchPlan.from_dict(SearchPlan(coarse_margin=None).to_dict()).coarse_margin is None
    for bad in (-0.1, float("nan"), "1", True):
        with pytest.raises(ValueError, match="coarse_margin"):
            SearchPlan(coarse_margin=bad)


def test_two_stage_search_finds_every_hit_of_the_full_search(default_model, test_frames):
    """On shipped frames, the cascade reports the same windows, margins and refined boxes."""
    from dataclasses import replace

    plan = default_model.detector_config.plan
    hits = 0
    for frame in test_frames:
        full = search(frame, default_model, replace(plan, coarse_margin=None))
        fast = search(frame, default_model, replace(plan, coarse_margin=1.5))
        assert np.array_equal(fast.xyxy, full.xyxy)
        np.testing.assert_allclose(fast.score, full.score, rtol=0, atol=1e-9)
        assert np.array_equal(fast.data["box"], full.data["box"])
        assert np.array_equal(fast.data["scale_index"], full.data["scale_index"])
        hits += len(full)
    assert hits > 50


def test_two_stage_search_scores_a_quarter_and_the_neighbours_exactly(default_model, test_frames):
    from vehicle_detection.search import _band, _score_band, _working_frame

    plan, cfg = default_model.detector_config.plan, default_model.config
    work, _ = _working_frame(test_frames[0], plan)
    scored = total = 0
    for s in plan.scales:
        band = _band(work, s, cfg, plan.overhang_of(s), plan.y_shift)
        full, _ = _score_band(band, default_model, reuse=False)
        two, _ = _score_band(band, default_model, reuse=False, cascade=(plan.threshold, 1.0))
        grid = two.reshape(len(band.rows), len(band.cols))
        assert np.isfinite(grid[::2, ::2]).all()  # the first stage: every other window both ways
        done = np.isfinite(two)
        np.testing.assert_allclose(two[done], full[done], rtol=0, atol=1e-9)
        # every window next to a first-stage window within the margin is scored, and no other
        near = np.zeros(grid.shape, bool)
        near[::2, ::2] = grid[::2, ::2] > plan.threshold - 1.0
        for dr in (-1, 0, 1):
            for dc in (-1, 0, 1):
                shifted = np.zeros_like(near)
                shifted[max(dr, 0) : near.shape[0] + min(dr, 0), max(dc, 0) : near.shape[1] + min(dc, 0)] = \
                    near[max(-dr, 0) : near.shape[0] - max(dr, 0), max(-dc, 0) : near.shape[1] - max(dc, 0)]
                assert done.reshape(grid.shape)[shifted].all()
        first = np.zeros(grid.shape, bool)
        first[::2, ::2] = True
        assert not (done.reshape(grid.shape) & ~first & ~_dilated(near)).any()
        scored, total = scored + done.sum(), total + done.size
    assert scored < 0.5 * total


def _dilated(a):
    out = a.copy()
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            out |= np.roll(np.roll(np.pad(a, 1), dr, 0), dc, 1)[1:-1, 1:-1]
    return out
