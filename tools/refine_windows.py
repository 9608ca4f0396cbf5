"""The box refinement learned from the windows the search accepts, against jittered windows only.

    python tools/refine_windows.py [OC]

Two ways to fit the refinement (:func:`vehicle_detection.training.with_box_refinement`):
``hot_iou=None``, windows jittered around each labelled car (the embedded model's until
2026-11-26), and
``hot_iou=0.5``, those plus the windows the model's own search accepts in the labelled frames
where they overlap a car at IoU 0.5 or more and jittering never draws them
(:func:`vehicle_detection.refine.hot_window_targets`, :func:`vehicle_detection.refine.beyond_jitter`;
the embedded model's now).

1. **Project camera, two folds.** Clip A's labelled frames are split into halves 30 frames apart
   (0-110 and 140-250, ``dev_set/clip_A.json``; ``clip_A_tracks.json``'s frames 140-149 with the
   second half). Each fold fits the refinement on one half, the test images and the dashcam's
   tune frames (as the README's rebuild does), and scores the other half, and, with ``OC`` (the
   folder of ``tools/other_cameras.py``), the same frames of every simulated view.
2. **Highway dashcam, its own frames.** The refinement fitted on ``highway_dashcam_tune.json``
   alone, scored on ``highway_dashcam_tune_extra.json`` (the tune split's frames in between,
   which no model is trained on).

With ``--embedded-out PATH`` only this runs instead:

3. **As the embedded model is fitted** (clip A, the test images and the dashcam's tune frames,
   the README's rebuild) with ``hot_iou=0.5``, saved to PATH, and scored on both cameras' tune
   frames (for the held-out frames, once: ``vehicle-detection evaluate --labels
   dev_set/highway_dashcam_heldout.json --model PATH``).

Every score is ``vehicle-detection evaluate --labels ... --model M --json`` on a model saved with
that refinement (the embedded classifier and settings otherwise): F1 at IoU 0.5 / 0.7 and the
mean IoU of matched boxes. The held-out frames are not scored here.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
DEV = REPO / "dev_set"
sys.path.insert(0, str(REPO / "tools"))
from model_variants import evaluate  # noqa: E402  the command line's scores, one line

HALVES = {"first": (0, 110), "second": (140, 250)}
VIEWS = ("tilted_down_960x540", "tilted_up_960x472", "tilted_down_1280x600", "zoomed_1.5x_1280x720",
         "zoomed_2x_1280x720", "dusk_0.2_1280x720", "dusk_0.2_tilted_up_960x472")


def half(labels: Path, name: str, out: Path) -> Path | None:
    """``labels`` with only the frames of half ``name``, its video named absolutely; None if no frame is left."""
    lo, hi = HALVES[name]
    data = json.loads(labels.read_text())
    data["frames"] = {k: v for k, v in data["frames"].items() if lo <= int(k) <= hi}
    if not data["frames"]:
        return None
    data["video"] = str((labels.parent / data["video"]).resolve())
    path = out / f"{labels.stem}_{name}.json"
    path.write_text(json.dumps(data))
    return path


def fitted(files: list[Path], hot_iou: float | None, path: Path) -> Path:
    """The embedded model with its refinement fitted on ``files``, saved to ``path``."""
    import vehicle_detection as vd
    from vehicle_detection.metrics.detection import load_annotations
    from vehicle_detection.training import with_box_refinement

    model = vd.load_default_model()
    refined = with_box_refinement(model, [load_annotations(f) for f in files], hot_iou=hot_iou)
    refined = refined.replace(detector_config=model.detector_config)  # the embedded settings, only the refinement fitted
    refined.save(path, overwrite=True)
    return path


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("oc", nargs="?", type=Path, help="the folder of tools/other_cameras.py (its views are scored too)")
    ap.add_argument("--embedded-out", type=Path, metavar="PATH",
                    help="only fit the embedded model's labels with hot_iou=0.5, save it here, and score both cameras' tune frames")
    args = ap.parse_args(argv)
    if args.embedded_out is not None:
        files = [DEV / "clip_A.json", DEV / "test_images.json", DEV / "highway_dashcam_tune.json"]
        model = fitted(files, 0.5, args.embedded_out)
        tune = {"project camera, tune": [DEV / "clip_A.json", DEV / "test_video.json", DEV / "test_images.json", DEV / "clip_A_tracks.json"],
                "highway dashcam, tune": [DEV / "highway_dashcam_tune.json", DEV / "highway_dashcam_tune_extra.json"],
                "its fourth set": [DEV / "highway_dashcam_tune_extra.json"]}
        for name, labels in tune.items():
            print(f"embedded labels, hot_iou 0.5  {name:24s} {evaluate(labels, model)}", flush=True)
        return
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for train, test in (("first", "second"), ("second", "first")):
            groups = {"project camera": [p for p in (half(DEV / "clip_A.json", test, tmp), half(DEV / "clip_A_tracks.json", test, tmp)) if p]}
            if args.oc is not None:
                for view in VIEWS:
                    groups[view] = [p for p in (half(args.oc / f"{view}_clip_A.json", test, tmp),) if p]
            files = [half(DEV / "clip_A.json", train, tmp), DEV / "test_images.json", DEV / "highway_dashcam_tune.json"]
            for hot in (None, 0.5):
                model = fitted(files, hot, tmp / f"model_{train}_{hot}.npz")
                for name, labels in groups.items():
                    print(f"fit on clip A's {train:6s} half, hot_iou {str(hot):4s}  {name:28s} {evaluate(labels, model)}", flush=True)
        for hot in (None, 0.5):
            model = fitted([DEV / "highway_dashcam_tune.json"], hot, tmp / f"model_highway_{hot}.npz")
            print(f"fit on the dashcam's tune frames, hot_iou {str(hot):4s}  {'its fourth set':28s} "
                  f"{evaluate([DEV / 'highway_dashcam_tune_extra.json'], model)}", flush=True)


if __name__ == "__main__":
    main()
