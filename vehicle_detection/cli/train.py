"""``vehicle-detection train``: a classifier, its honest accuracies, and the saved model."""

from __future__ import annotations

import json
import time
from pathlib import Path

from ..classifier import DEFAULT_C
from ..errors import InputError, OutputError, require
from ..io import check_output_path
from ..metrics.detection import load_annotations
from ..training.augment import AugmentConfig
from ..training.data import CLASSES, check_split_sizes, default_data_dir, list_extra_negatives, load_dataset
from ..training.fit import train, with_box_refinement
from ..training.mining import labelled_dataset
from .options import feature_config, human_print

__all__ = ["run"]


def _train_report(model) -> dict:
    m = model.metrics
    r, g = m.get("random_split", {}), m.get("grouped_split", {})
    return {
        "random_split_accuracy": r.get("accuracy"),
        "grouped_split_accuracy": g.get("accuracy"),
        "random_split_precision": r.get("precision"),
        "random_split_recall": r.get("recall"),
        "grouped_split_precision": g.get("precision"),
        "grouped_split_recall": g.get("recall"),
        "n_train": r.get("n_train"),
        "n_test": r.get("n_test"),
        "grouped_n_train": g.get("n_train"),
        "grouped_n_test": g.get("n_test"),
        "n_images": m.get("n_images"),
        "n_augmented": m.get("augment", {}).get("n_copies", 0),
        "augment_seconds": m.get("augment", {}).get("seconds", 0.0),
        "n_features": m.get("n_features"),
        "load_seconds": m.get("load_seconds"),
        "feature_seconds": m.get("feature_seconds"),
        "fit_seconds": m.get("fit_seconds"),
    }


def run(args) -> int:
    config = feature_config(args)
    if args.classifier == "convnet":
        if not args.labels:
            raise InputError("--classifier convnet learns the cars' edges from labelled frames: pass --labels")
        require("torch", "train-cnn", "train --classifier convnet")
    root = default_data_dir(args.data_dir)
    labels = [load_annotations(p) for p in args.labels]
    if args.model is not None:
        # the labels, their videos and image folders, and the extra negatives' folders are inputs too
        read = [*args.labels, *(a.source for a in labels if a.source is not None), *(args.extra_negatives or [])]
        _check_model_output(args.model, root, overwrite=args.overwrite, inputs=read)
    t = time.perf_counter()
    archives = load_dataset(args.data_dir, drop_duplicates=args.drop_duplicates, extra_negatives=args.extra_negatives)
    load_s = time.perf_counter() - t
    traffic = args.traffic or "right"
    ds = archives.concatenate(labelled_dataset(labels, flip=traffic == "left")) if labels else archives
    check_split_sizes(ds.labels, ds.groups, name=str(root))  # before any feature is computed
    augment = AugmentConfig(copies=args.augment)
    model = train(ds, config, C=args.C if args.C is not None else DEFAULT_C, random_state=args.seed, augment=augment)
    model = model.replace(detector_config=model.detector_config.replace(traffic=traffic))
    if args.classifier == "convnet":
        from ..training.convnet import ConvNetTraining, with_convnet

        say_ = human_print(args)
        say_(f"network: training on {len(archives)} patches and the labelled frames of {len(labels)} labels files "
             f"({args.rounds} rounds of {args.epochs} epochs)")
        model = with_convnet(model, archives, labels, ConvNetTraining(epochs=args.epochs, seed=args.seed), rounds=args.rounds,
                             progress=not args.json)
    elif labels:
        model = with_box_refinement(model, labels)
    extra = {}
    if args.extra_negatives:
        extra_sources = {source for d in args.extra_negatives for source, _ in list_extra_negatives(d)}
        extra = {"extra_negatives": {k: v for k, v in ds.counts().items() if k in extra_sources}}
    model = model.replace(metrics={**model.metrics, "load_seconds": round(load_s, 3), "drop_duplicates": bool(args.drop_duplicates), **extra})
    report = _train_report(model)
    say = human_print(args)
    m = model.metrics
    say(f"images: {m['n_images']} ({', '.join(f'{k} {v}' for k, v in ds.counts().items())})")
    if "augment" in m:
        say(f"augmented: {m['augment']['n_copies']} copies ({args.augment} per image, {m['augment']['seconds']:.1f} s)")
    say(f"features: {m['n_features']} per image ({config})")
    for name in ("random_split", "grouped_split"):
        s = m[name]
        say(
            f"{name.replace('_', ' ')}: accuracy {s['accuracy']:.4f}  precision {s['precision']:.4f}  "
            f"recall {s['recall']:.4f}  (train {s['n_train']}, test {s['n_test']})"
        )
    say(f"time: load {load_s:.1f} s, features {m['feature_seconds']:.1f} s, final fit {m['fit_seconds']:.1f} s (all {m['n_images']} images)")
    if args.model is not None:
        model.save(args.model, overwrite=args.overwrite, inputs=read)
        say(f"model saved to {args.model}")
    else:
        say("model not saved (pass --model OUT.npz to save it)")
    if args.json:
        print(json.dumps(report))
    return 0


def _check_model_output(model, root: Path, *, overwrite: bool, inputs=()) -> None:
    """The training data are inputs: ``--model`` may not be an archive or lie in a class folder,
    nor be or lie in any of ``inputs``."""
    model = Path(model)
    check_output_path(model, overwrite=overwrite, inputs=[*(root / f"{c}.zip" for c in CLASSES), *inputs])
    target = model.resolve()
    for cls in CLASSES:
        folder = (root / cls).resolve()
        if target == folder or folder in target.parents:
            raise OutputError(
                f"{model}: model path is inside the training images folder {root / cls}; save the model elsewhere"
            )
