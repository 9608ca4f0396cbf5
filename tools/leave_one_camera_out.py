"""Leave one camera out: for each labelled camera, a model built without any of its frames, scored on them.

    python tools/leave_one_camera_out.py [--classifier cnn|svm] [--cameras NAME ...] [--work DIR]

For each camera C of ``CAMERAS`` (those whose footage is in ../shared/data): train on the archives
(without ``non-vehicles/Extras``, which are frames of the project camera, when C is the project
camera) and the training labels of every other camera, then score every labelled frame of C with
``vehicle-detection evaluate``. ``--all`` also trains on every camera and scores each camera's
held-out split (the measure of a camera with labels). Prints one table: F1 at IoU 0.5 / 0.7 and
the mean IoU of matched boxes, per camera, and their means.

``--classifier cnn`` trains the window-scoring network (:mod:`vehicle_detection.training.convnet`,
needs the ``train-cnn`` extra) and saves it in a model beside the embedded model's SVM;
``svm`` runs the README's ``train`` command (HOG + linear SVM, with the box refinement).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DEV = ROOT / "dev_set"

#: camera -> (training labels, labels scored when it is left out, held-out labels)
CAMERAS = {
    "project": (["clip_A.json", "test_images.json"],
                ["clip_A.json", "test_video.json", "test_images.json", "clip_A_tracks.json"], []),
    "highway_dashcam": (["highway_dashcam_tune.json"],
                        ["highway_dashcam_tune.json", "highway_dashcam_tune_extra.json", "highway_dashcam_heldout.json"],
                        ["highway_dashcam_heldout.json"]),
    "city_india": (["city_india_tune.json"], ["city_india_tune.json", "city_india_heldout.json"], ["city_india_heldout.json"]),
    "autobahn": (["autobahn_tune.json"], ["autobahn_tune.json", "autobahn_heldout.json"], ["autobahn_heldout.json"]),
    "residential": (["residential_tune.json"], ["residential_tune.json", "residential_heldout.json"], ["residential_heldout.json"]),
}


def available(names):
    from vehicle_detection.metrics.detection import load_annotations

    out = []
    for name in names:
        files = CAMERAS[name][0] + CAMERAS[name][1]
        if all((DEV / f).exists() for f in files):
            src = load_annotations(DEV / CAMERAS[name][0][0]).source
            if src is not None and src.exists():
                out.append(name)
                continue
        print(f"{name}: skipped (labels or footage missing)", file=sys.stderr)
    return out


def folds(left_out: list[str], pool: list[str]) -> list[tuple[str, list[str], list[str], bool]]:
    """For each camera left out: ``(camera, training cameras, label files scored, whether the
    archives' project-camera negatives are left out too)``. No training camera is the one scored."""
    return [(cam, [c for c in pool if c != cam], CAMERAS[cam][1], cam == "project") for cam in left_out]


def training_labels(cameras: list[str]) -> list[Path]:
    """The label files the models train on for these cameras."""
    return [DEV / f for c in cameras for f in CAMERAS[c][0]]


def evaluate(model: Path, labels: list[str]) -> dict:
    cmd = ["vehicle-detection", "evaluate", "--labels", *[str(DEV / f) for f in labels], "--model", str(model), "--json"]
    out = subprocess.run(cmd, check=False, capture_output=True, text=True)
    if out.returncode:
        raise SystemExit(f"evaluate failed: {' '.join(cmd)}\n{out.stderr[-2000:]}")
    return json.loads(out.stdout)["all"]


def build_cnn(train_cams: list[str], out: Path, *, without_extras: bool, args) -> dict:
    """The whole network model from the archives and the training cameras' labels, as
    ``vehicle-detection train --classifier convnet`` builds it: the SVM (kept in the file, unused
    by the search), then the network in rounds with hard negatives."""
    from vehicle_detection.classifier import load_default_model
    from vehicle_detection.metrics.detection import load_annotations
    from vehicle_detection.training.convnet import ConvNetTraining, with_convnet
    from vehicle_detection.training.data import load_dataset
    from vehicle_detection.training.fit import train

    archives = load_dataset(args.data_dir)
    if without_extras:
        archives = archives.subset(archives.sources != "non-vehicles/Extras")
    anns = [load_annotations(f) for f in training_labels(train_cams)]
    print(f"  {len(archives)} archive patches; {len(anns)} label files", flush=True)
    model = train(archives, load_default_model().config, evaluate=False)
    model = with_convnet(model, archives, anns, ConvNetTraining(epochs=args.epochs, wide=args.wide), rounds=args.rounds, progress=args.verbose)
    _settings(model, args).save(out, overwrite=True)
    return model.metrics["convnet"]


def _settings(model, args):
    """The network model's detector settings (:func:`vehicle_detection.training.convnet.detector_settings`)."""
    from vehicle_detection.classifier import load_default_model
    from vehicle_detection.training.convnet import detector_settings

    dc = detector_settings(load_default_model().detector_config, threshold=args.threshold, candidates=args.candidates,
                           small=not args.no_small, large=not args.no_large, wide=args.wide)
    return model.replace(detector_config=dc)


def build_svm(train_cams: list[str], out: Path, *, without_extras: bool, args) -> dict:
    """The seeds' model as ``vehicle-detection train --labels`` builds it: HOG + linear SVM on the
    archives and the training cameras' cars, with the box refinement fitted on their frames (no
    mined negatives: the embedded model's rebuild adds two rounds of them)."""
    from vehicle_detection.classifier import load_default_model
    from vehicle_detection.metrics.detection import load_annotations
    from vehicle_detection.training.data import load_dataset
    from vehicle_detection.training.fit import train, with_box_refinement
    from vehicle_detection.training.mining import labelled_dataset

    archives = load_dataset(args.data_dir)
    if without_extras:
        archives = archives.subset(archives.sources != "non-vehicles/Extras")
    anns = [load_annotations(f) for f in training_labels(train_cams)]
    model = train(archives.concatenate(labelled_dataset(anns)), load_default_model().config, evaluate=False)
    model = with_box_refinement(model, anns)
    model.save(out, overwrite=True)
    return {}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--classifier", choices=("cnn", "svm"), default="cnn")
    p.add_argument("--cameras", nargs="*", default=list(CAMERAS))
    p.add_argument("--pool", nargs="*", default=list(CAMERAS), help="the cameras that may train (default: all)")
    p.add_argument("--data-dir", default=str(ROOT.parent / "shared" / "data"))
    p.add_argument("--work", default="loco_models")
    p.add_argument("--epochs", type=int, default=8)
    p.add_argument("--rounds", type=int, default=2)
    p.add_argument("--threshold", type=float, default=2.0)
    p.add_argument("--candidates", type=float, nargs="+", default=[0.19, 0.27, 0.35, 0.43, 0.51, 0.59, 0.67])
    p.add_argument("--no-small", action="store_true", help="without the 48-pixel windows")
    p.add_argument("--no-large", action="store_true", help="without the 384-pixel windows")
    p.add_argument("--wide", type=float, default=1.0, help="width over height of the wide windows (1: none; 2 measured worse)")
    p.add_argument("--all", action="store_true", help="also train on every camera and score the held-out splits")
    p.add_argument("--reuse", action="store_true", help="score models already in --work")
    p.add_argument("--verbose", action="store_true")
    args = p.parse_args(argv)
    cams = available(args.cameras)
    everyone = available(args.pool)
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    build = build_cnn if args.classifier == "cnn" else build_svm
    rows = []
    for cam, train_cams, scored, without_extras in folds(cams, everyone):
        model = work / f"{args.classifier}_without_{cam}.npz"
        t = time.perf_counter()
        if args.reuse and model.exists():
            model = _rescored(model, args) if args.classifier == "cnn" else model
        else:
            print(f"{cam}: training without it on {train_cams}", flush=True)
            build(train_cams, model, without_extras=without_extras, args=args)
        pooled = evaluate(model, scored)
        rows.append(("left out", cam, pooled))
        print(f"{cam}: {_fmt(pooled)} ({time.perf_counter() - t:.0f} s)", flush=True)
    if args.all:
        model = work / f"{args.classifier}_all.npz"
        if args.reuse and model.exists():
            model = _rescored(model, args) if args.classifier == "cnn" else model
        else:
            build(everyone, model, without_extras=False, args=args)
        for cam in everyone:
            if CAMERAS[cam][2]:
                rows.append(("held out", cam, evaluate(model, CAMERAS[cam][2])))
        rows.append(("tune", "project", evaluate(model, CAMERAS["project"][1])))
    print(f"\n| split | camera | cars | F1 at IoU 0.5 / 0.7 | mean IoU |  ({args.classifier})")
    print("| --- | --- | --- | --- | --- |")
    for split, cam, pooled in rows:
        print(f"| {split} | {cam} | {pooled['n_cars']} | {pooled['at_iou_0.5']['f1']:.3f} / {pooled['at_iou_0.7']['f1']:.3f} | {pooled['at_iou_0.5']['mean_iou']:.3f} |")
    loco = [r[2] for r in rows if r[0] == "left out"]
    if loco:
        m5 = np.mean([r["at_iou_0.5"]["f1"] for r in loco])
        m7 = np.mean([r["at_iou_0.7"]["f1"] for r in loco])
        print(f"| left out | mean of {len(loco)} | | {m5:.3f} / {m7:.3f} | |")
    return 0


def _rescored(path: Path, args) -> Path:
    """A copy of a saved network model with the settings of ``args`` (to score it again)."""
    from vehicle_detection.classifier import load_model

    out = path.with_name(f"{path.stem}_t{args.threshold:g}{'_nosmall' if args.no_small else ''}{'_nolarge' if args.no_large else ''}.npz")
    _settings(load_model(path), args).save(out, overwrite=True)
    return out


def _fmt(p):
    return (f"F1 {p['at_iou_0.5']['f1']:.3f} / {p['at_iou_0.7']['f1']:.3f}, mean IoU {p['at_iou_0.5']['mean_iou']:.3f} "
            f"(tp {p['at_iou_0.5']['tp']}, fp {p['at_iou_0.5']['fp']}, fn {p['at_iou_0.5']['fn']})")


if __name__ == "__main__":
    raise SystemExit(main())
