"""How a box refinement fitted on one camera's frames moves the windows of another camera (docs/experiments.md, "A stronger ridge penalty").

    python tools/refine_transfer.py [--alpha A [A ...]]

The refinement is fitted as ``train --labels`` fits it
(:func:`vehicle_detection.refine.fit_box_regressor`: windows jittered around each labelled car and
the windows the embedded model's search accepts beyond the jitter), with the embedded classifier's
features, on one camera's frames:

* project camera: ``dev_set/clip_A.json`` and ``dev_set/test_images.json``;
* highway dashcam: ``dev_set/highway_dashcam_tune.json`` (needs the clip in ``../shared/data``).

It is then scored, before any heat, tracking or side fit, on the windows the search accepts (IoU
0.5 or more with a labelled car) in frames no refinement here was fitted on: the project camera's
``clip_A_tracks.json`` and ``test_video.json``, the dashcam's ``highway_dashcam_tune_extra.json``.
Each window is refined from its crop's features, as the fit sees them. Printed for each ridge
penalty: the mean IoU of the refined windows with their cars and the share at IoU 0.7 or more, for
each pair (fitted on, scored on), beside the windows as the search gives them.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

import vehicle_detection as vd
from vehicle_detection.features import extract_features
from vehicle_detection.geometry import box_iou
from vehicle_detection.metrics.detection import load_annotations
from vehicle_detection.refine import crop_windows, fit_box_regressor, hot_window_targets, working_frame

DEV = Path(__file__).resolve().parents[1] / "dev_set"
FIT = {"project": ["clip_A.json", "test_images.json"], "dashcam": ["highway_dashcam_tune.json"]}
SCORE = {"project": ["clip_A_tracks.json", "test_video.json"], "dashcam": ["highway_dashcam_tune_extra.json"]}


def searched_frames(model, files: list[str]):
    """``(frame, its cars, the boxes found)`` of every labelled frame of ``files`` (dev_set names)."""
    from vehicle_detection.training.fit import _searched_frames  # scikit-learn's import: not for --help

    return _searched_frames(model, [load_annotations(DEV / f) for f in files])


def accepted_windows(model, files: list[str]) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """``(working frame, windows, their cars)`` of every labelled frame: the windows the search
    accepts at IoU 0.5 or more with a car, in the working frame's pixels."""
    out = []
    for frame, cars, found in searched_frames(model, files):
        work, f = working_frame(frame, model.detector_config.plan.reference_height)
        wins, theirs = hot_window_targets(np.asarray(found, np.float64).reshape(-1, 4) * f, np.asarray(cars, np.float64).reshape(-1, 4) * f, 0.5)
        if len(wins):
            out.append((work, np.rint(wins), theirs))
    return out


def scores(items, model, regressor) -> tuple[float, float]:
    """Mean IoU of the (refined) windows with their cars, and the share at 0.7 or more."""
    ious = []
    for work, wins, cars in items:
        boxes = wins if regressor is None else regressor.refine(wins, extract_features(crop_windows(work, wins, model.config.window), model.config), work.shape)
        ious.append(np.diag(box_iou(np.asarray(boxes, np.float64), cars)))
    ious = np.concatenate(ious)
    return float(ious.mean()), float((ious >= 0.7).mean())


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--alpha", type=float, nargs="+", default=[1e3, 1e4], help="ridge penalties (default: 1e3 1e4)")
    args = ap.parse_args(argv)
    model = vd.load_default_model()
    samples = {cam: list(searched_frames(model, files)) for cam, files in FIT.items()}
    scored = {cam: accepted_windows(model, files) for cam, files in SCORE.items()}
    for cam, items in scored.items():
        print(f"{cam} windows, as the search gives them: mean IoU %.3f, IoU >= 0.7 %.2f (%d windows)"
              % (*scores(items, model, None), sum(len(w) for _, w, _ in items)))
    for alpha in args.alpha:
        for fitted_on, frames in samples.items():
            regressor = fit_box_regressor(frames, model.config, alpha=alpha, reference_height=model.detector_config.plan.reference_height)
            for cam, items in scored.items():
                print(f"alpha {alpha:g}: fitted on the {fitted_on}, {cam} windows: mean IoU %.3f, IoU >= 0.7 %.2f" % scores(items, model, regressor), flush=True)


if __name__ == "__main__":
    main()
