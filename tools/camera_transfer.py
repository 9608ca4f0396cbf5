"""Leave one camera out: train on one dev camera's data, score on the other's tune frames (writeup 3.4).

    python tools/camera_transfer.py [--data-dir ../shared/data] [--negatives data/negatives]
                                    [--variant NAME "TRAIN ARGS"]...

How a model does on a camera nobody labelled, estimated with the two dev cameras. For each
camera, a model is trained by the command line, as the README's rebuild trains the embedded
one, but with that camera's data only: the archives, the cars of its tune frames (``--labels``,
which also fit the box refinement) and its own mined negatives (the README's ``mine-negatives``
commands write them to ``data/negatives/non-vehicles/<name>/``: ``ProjectTune`` and
``ProjectStills`` are the project camera's, ``HighwayTune`` the dashcam's). The model is then
scored by ``vehicle-detection evaluate`` on the tune frames of both cameras: its own (frames it
learned, the upper bound) and the other (a camera it never saw).

A ``--variant`` adds training options, e.g. ``--variant hog-only "--spatial-size 0 --hist-bins
0"`` (the feature vector without the colour features) or ``--variant augmented "--augment 1"``.
Without any, the default features (``default``) and those two are measured. Each model takes
about a minute to train and half a minute to score per camera.

Prints one line per variant, camera trained on and camera scored: F1 at IoU 0.5 and 0.7, mean IoU
of matched boxes, true and false positives, misses.
"""

from __future__ import annotations

import argparse
import shlex
import shutil
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
VARIANTS = {"default": "", "hog-only": "--spatial-size 0 --hist-bins 0", "augmented": "--augment 1"}


def camera_negatives(negatives: Path, sources: tuple[str, ...], folder: Path) -> Path:
    """A folder laid out for ``train --extra-negatives`` holding copies of ``sources`` only."""
    for name in sources:
        source = negatives / "non-vehicles" / name
        if not source.is_dir():
            raise SystemExit(f"{source}: no such folder of mined negatives (the README's mine-negatives commands write it)")
        shutil.copytree(source, folder / "non-vehicles" / name)
    return folder


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data-dir", type=Path, default=REPO.parent / "shared" / "data", help="the training archives")
    ap.add_argument("--negatives", type=Path, default=REPO / "data" / "negatives", help="the mined negatives")
    ap.add_argument("--variant", nargs=2, action="append", metavar=("NAME", "TRAIN_ARGS"),
                    help="a name and extra `train` options (repeatable); default: " + ", ".join(VARIANTS))
    args = ap.parse_args(argv)
    variants = dict(args.variant) if args.variant else VARIANTS
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for variant, options in variants.items():
            for trained, (labels, sources) in CAMERAS.items():
                negatives = camera_negatives(args.negatives, sources, tmp / f"negatives_{len(list(tmp.iterdir()))}")
                model = tmp / f"model_{len(list(tmp.iterdir()))}.npz"
                cli("train", "--data-dir", str(args.data_dir), "--labels", *map(str, labels),
                    "--extra-negatives", str(negatives), "--model", str(model), *shlex.split(options))
                for scored, files in GROUPS.items():
                    seen = "its own" if scored == trained else "unseen"
                    print(f"{variant:10s} trained on {trained:13s} scored on {scored:13s} ({seen:7s}) {evaluate(files, model)}", flush=True)


if __name__ == "__main__":
    main()
