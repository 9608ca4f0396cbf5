"""Dev-set F1 with scales 1.5 and 3 taken from a shared pyramid's octaves (docs/experiments.md, "One gradient pass shared by all scales").

    python tools/pyramid_f1.py [--shift S15 S3] [--control]

``tools/pyramid_margins.py`` measures how the margins move when the HOG of scale 1.5 comes from
octave 1 (the working frame, 12-pixel cells) and that of scale 3 from octave 2 (the frame at half
size, 12-pixel cells), as Dollar et al.'s fast feature pyramids approximate the scales between
octaves. This tool measures what that does to detection: the embedded detector runs over the
tune frames of both dev cameras with those two scales' windows scored from the approximated
features (their spatial bins and histograms as today, their margins moved by ``--shift``, the
mean change's opposite; their refined boxes from the same features), every other scale as
today, and prints F1 at IoU 0.5 and 0.7 and the mean IoU of matched boxes per camera.

It is a measurement, not a search: each frame is searched whole once for every window's margin,
and the two scales' windows are cut out and described again, one by one (slow). It replaces the
detector module's ``search`` for its own run (nothing outside this process is touched).
The detector searches windows as their crops (``window_border="crop"``, threshold 0.3: the
search the pyramids approximate). ``--control`` keeps those features through the same path: it
must print the figures of ``vehicle-detection evaluate --model M`` exactly, with ``M`` the
embedded model with that plan (the check that the path is the crop search's).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
GROUPS = {
    "project tune": ["clip_A.json", "test_video.json", "test_images.json", "clip_A_tracks.json"],
    "highway tune": ["highway_dashcam_tune.json", "highway_dashcam_tune_extra.json"],
}
APPROXIMATED = {1.5: 1, 3.0: 2}  # scale -> the octave its HOG is taken from


def approximated_features(work, model, plan, k, control=False):
    """Feature vectors of every window of the plan's scale ``k`` (the search's order), with the
    HOG from the scale's octave."""
    from vehicle_detection.features import convert_color, extract_features, hog_features, hog_input
    from vehicle_detection.search import _band

    sys.path.insert(0, str(REPO / "tools"))
    from pyramid_margins import crops, octave_patches

    cfg, s = model.config, plan.scales[k]
    band = _band(work, s, cfg, plan.overhang_of(s), plan.y_shift)
    ppc, side = cfg.pixels_per_cell, cfg.window
    rr, cc = np.meshgrid(band.rows * ppc, band.cols * ppc, indexing="ij")
    corners = np.stack([cc.ravel(), rr.ravel()], axis=1)
    feats = extract_features(crops(band.image, corners, side), cfg)
    if control:
        return feats
    patches, cell = octave_patches(work, band, corners, s.scale, APPROXIMATED[s.scale], cfg)
    big = dataclasses.replace(cfg, window=patches.shape[1], pixels_per_cell=cell)
    feats[:, cfg.layout()["hog"]] = hog_features(hog_input(convert_color(patches, cfg.color_space), big), big)
    return feats


def pyramid_search(shift: dict, control: bool):
    """A stand-in for :func:`vehicle_detection.search.search` (whole frames only)."""
    from vehicle_detection import search as S
    from vehicle_detection.detections import Detections

    exact = S.search

    def search(frame, model, plan=None, *, all_windows=False, around=None):
        if around is not None or all_windows:
            raise NotImplementedError("whole-frame searches only")
        plan = model.detector_config.plan if plan is None else plan
        every = exact(frame, model, plan, all_windows=True)  # every window's margin, in band order
        today = exact(frame, model, plan)  # the hot windows and their refined boxes, as today
        work, f = S._working_frame(frame, plan)
        parts = []
        for k, s in enumerate(plan.scales):
            if s.scale not in APPROXIMATED:  # as today (its two-stage search included)
                parts.append(today[today.data["scale_index"] == k])
                continue
            where = np.flatnonzero(every.data["scale_index"] == k)
            if not len(where):
                continue
            feats = approximated_features(work, model, plan, k, control)
            score = model.decision_function(feats) + (0.0 if control else shift[s.scale])
            hot = score > plan.threshold
            band = S._band(work, s, model.config, plan.overhang_of(s), plan.y_shift)
            windows = S._band_windows(band, model.config, f, hot)
            boxes = model.box_regressor.refine(windows, feats[hot], frame.shape) if hot.any() else np.zeros((0, 4), np.int64)
            mine = every[where[hot]].replace(score=score[hot])
            parts.append(mine.replace(data={**mine.data, "box": boxes}))
        return Detections.concatenate(parts) if parts else today[:0]

    return search


def main(argv: list[str] | None = None) -> None:
    import vehicle_detection as vd
    import vehicle_detection.detector as detector_module
    from vehicle_detection.metrics.detection import evaluation_report, pool_reports
    from vehicle_detection.metrics.runner import detect_labelled

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--shift", nargs=2, type=float, default=(0.40, 0.31), metavar=("S15", "S3"),
                    help="added to the approximated margins of scales 1.5 and 3 (default: the opposite of "
                    "tools/pyramid_margins.py's mean changes, 0.40 0.31)")
    ap.add_argument("--control", action="store_true", help="the crop search's features through the same path")
    args = ap.parse_args(argv)
    detector_module.search = pyramid_search(dict(zip(APPROXIMATED, args.shift)), args.control)
    sys.path.insert(0, str(REPO / "tools"))
    from pyramid_margins import crop_search

    model = crop_search(vd.load_default_model())
    detector = vd.Detector(model)
    for name, files in GROUPS.items():
        reports = []
        for file in files:
            labels = vd.load_annotations(REPO / "dev_set" / file)
            found, fps = detect_labelled(labels, detector)
            reports.append(evaluation_report(found, labels, fps=fps))
        r = pool_reports(reports)
        a, b = r["at_iou_0.5"], r["at_iou_0.7"]
        what = "control (the crop search's features)" if args.control else f"octaves, shift {args.shift[0]:g} / {args.shift[1]:g}"
        print(f"{what}: {name}: F1 {a['f1']:.3f} / {b['f1']:.3f}, mean IoU {a['mean_iou']:.3f} "
              f"(tp {a['tp']}, fp {a['fp']}, fn {a['fn']})", flush=True)


if __name__ == "__main__":
    main()
