"""``vehicle-detection refine``: a model's box refinement fitted to labelled frames of your camera."""

from __future__ import annotations

import json
import time

from ..classifier import VehicleClassifier, load_default_model
from ..errors import InputError
from ..io import check_output_path
from ..metrics.detection import load_annotations
from ..refine import REFINE_ALPHA
from ..training.fit import with_box_refinement
from .options import human_print

__all__ = ["run"]


def run(args) -> int:
    labels = [load_annotations(p) for p in args.labels]
    # the labelled videos and image folders are inputs too
    inputs = [*args.labels, *(a.source for a in labels if a.source is not None), *([args.model] if args.model is not None else [])]
    check_output_path(args.out, overwrite=args.overwrite, inputs=inputs)  # before any work
    model = load_default_model() if args.model is None else VehicleClassifier.load(args.model)
    if model.convnet is not None:
        raise InputError(f"{args.model}: a network model gives each window's edges itself; refine fits the box refinement "
                         "of an SVM model (train the network with your labels instead: train --classifier convnet --labels ...)")
    n_frames = sum(len(a.frames) for a in labels)
    n_cars = sum(a.n_cars for a in labels)
    if n_cars == 0:
        raise InputError(f"{', '.join(map(str, args.labels))}: no labelled cars to fit the box refinement on")
    base = model.metrics.get("box_refinement", {})
    alpha = args.alpha if args.alpha is not None else base.get("alpha", REFINE_ALPHA)
    mirror = args.mirror if args.mirror is not None else bool(base.get("mirror", False))
    tracker = model.detector_config.tracker
    # A model that refines already keeps its clustering and voting; one that does not gets the defaults.
    keep = {"cluster_iou": tracker.cluster_iou, "box_vote": tracker.box_vote} if model.box_regressor is not None else {}
    t = time.perf_counter()
    refined = with_box_refinement(model, labels, alpha=alpha, mirror=mirror, traffic=args.traffic, **keep)
    seconds = time.perf_counter() - t
    refined.save(args.out, overwrite=args.overwrite, inputs=inputs)
    say = human_print(args)
    flipped = ", the frames flipped too" if mirror else ""
    say(f"box refinement fitted on {n_cars} cars in {n_frames} labelled frames ({seconds:.1f} s, ridge penalty {alpha:g}{flipped}); "
        f"classifier and search as in {args.model or 'the embedded model'}")
    say(f"model saved to {args.out}")
    if args.json:
        print(json.dumps({"n_frames": n_frames, "n_cars": n_cars, "alpha": alpha, "mirror": mirror, "seconds": round(seconds, 3),
                          "model": str(args.out)}))
    return 0
