"""Leave one camera out: train on one dev camera's data, score on both cameras' tune frames (docs/experiments.md, "Features and augmentation for a camera no labels come from").

    python tools/camera_transfer.py [--data-dir ../shared/data] [--negatives data/negatives]
                                    [--variant NAME=TRAIN_ARGS]...

How a model does on a camera nobody labelled, estimated with the two dev cameras. For each
camera, a model is trained by the command line, as the README's rebuild trains the embedded
one, but with that camera's data only: the archives, the cars of its tune frames (``--labels``,
which also fit the box refinement) and its own mined negatives (the README's ``mine-negatives``
commands write them to ``data/negatives/non-vehicles/<name>/``: ``ProjectTune`` and
``ProjectStills`` are the project camera's, ``HighwayTune`` the dashcam's). The model is then
scored by ``vehicle-detection evaluate`` on the tune frames of both cameras: the other camera's
(a camera it never saw) and its own (partly frames it learned from: an optimistic figure).

A ``--variant`` adds training options, e.g. ``--variant "hog-only=--spatial-size 0 --hist-bins 0"``
(the feature vector without the colour features) or ``--variant augmented=--augment 1``.
Without any, the default features (``default``) and those two are measured.

Prints one line per variant, camera trained on and camera scored: F1 at IoU 0.5 and 0.7, the mean
IoU of matched boxes, true and false positives and misses at IoU 0.5, and HOTA (AssA) where the
labels carry track ids.
"""

from __future__ import annotations

import argparse
import shlex
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from model_variants import DEV, GROUPS, REPO, cli, evaluate  # noqa: E402  the same scoring

#: Each dev camera: its tune frames' labels given to ``train`` and its mined negatives' sources.
CAMERAS = {
    "project tune": ([DEV / "clip_A.json", DEV / "test_images.json"], ("ProjectTune", "ProjectStills")),
    "highway tune": ([DEV / "highway_dashcam_tune.json"], ("HighwayTune",)),
}
assert CAMERAS.keys() == GROUPS.keys()  # each camera is scored on its own group of tune frames
VARIANTS = {"default": "", "hog-only": "--spatial-size 0 --hist-bins 0", "augmented": "--augment 1"}


def negatives_options(negatives: Path, sources: tuple[str, ...]) -> list[str]:
    """``train``'s ``--extra-negatives`` options for the mined negatives of ``sources`` only."""
    options = []
    for name in sorted(sources):  # in the order of one folder holding them all
        folder = negatives / "non-vehicles" / name
        if not folder.is_dir():
            raise SystemExit(f"{folder}: no such folder of mined negatives (the README's mine-negatives commands write it)")
        options += ["--extra-negatives", str(folder)]
    return options


def variant(text: str) -> tuple[str, str]:
    """``NAME=TRAIN_ARGS`` as (name, args)."""
    name, sep, options = text.partition("=")
    if not sep or not name:
        raise argparse.ArgumentTypeError(f"{text!r}: give NAME=TRAIN_ARGS, e.g. 'augmented=--augment 1'")
    return name, options


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data-dir", type=lambda p: Path(p).resolve(), default=REPO.parent / "shared" / "data", help="the training archives")
    ap.add_argument("--negatives", type=lambda p: Path(p).resolve(), default=REPO / "data" / "negatives", help="the mined negatives")
    ap.add_argument("--variant", type=variant, action="append", metavar="NAME=TRAIN_ARGS",
                    help="a name and extra `train` options (repeatable); default: " + ", ".join(VARIANTS))
    args = ap.parse_args(argv)
    variants = dict(args.variant) if args.variant else VARIANTS
    with tempfile.TemporaryDirectory() as tmp:
        for name, options in variants.items():
            for trained, (labels, sources) in CAMERAS.items():
                model = Path(tmp) / f"{name}_{trained.split()[0]}.npz"
                cli("train", "--data-dir", str(args.data_dir), "--labels", *map(str, labels),
                    *negatives_options(args.negatives, sources), "--model", str(model), "--overwrite", *shlex.split(options))
                for scored, files in GROUPS.items():
                    seen = "its own" if scored == trained else "unseen"
                    print(f"{name:10s} trained on {trained:13s} scored on {scored:13s} ({seen:7s}) {evaluate(files, model)}", flush=True)


if __name__ == "__main__":
    main()
