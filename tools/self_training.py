"""Self-training on a camera no labels come from: the detector's own tracks as its labels (docs/experiments.md, "Self-training").

    python tools/self_training.py [--data-dir ../shared/data] [--negatives data/negatives]
                                  [--rounds 10 40] [--stride 7]

A model trained without any of the highway dashcam's data (the archives, the project camera's
tune cars and its mined negatives, as ``tools/camera_transfer.py`` trains it) runs ``detect`` on
the dashcam's video. The boxes of its tracks on the tune split's frames (``dev_set/README.md``:
frames 0-175 and 363-433; every ``--stride``-th frame, tracks at least that round's number of
frames long) are written as a labels file, and a model is trained on the same data plus these
pseudo-labels (``train --labels``: vehicle patches and box refinement), as a user without labels
could do on their own footage. Each of ``--rounds`` (a minimum track length per round) starts
from the model of the round before.

Prints, per round: the pseudo-labels (how many of those on labelled frames match a labelled car
at IoU 0.5 or more, or lie in an ignore region, as ``evaluate`` matches a frame's boxes), then
``vehicle-detection evaluate`` of the model on both cameras' tune frames. The dashcam's scores
are on the frames whose video gave the pseudo-labels (no labels were used to make them); the
held-out frames are not scored.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from camera_transfer import CAMERAS, negatives_options  # noqa: E402  the same training
from model_variants import GROUPS, REPO, cli, evaluate  # noqa: E402  the same scoring

from vehicle_detection.io.tables import read_boxes_csv  # noqa: E402
from vehicle_detection.metrics.detection import load_annotations, match_frame  # noqa: E402

VIDEO = "videos/highway_dashcam_854x480.mp4"
#: The dashcam's tune split (dev_set/README.md), inclusive ranges of frame indexes.
TUNE = ((0, 175), (363, 433))


def pseudo_labels(boxes_csv: Path, video: Path, out: Path, *, stride: int, min_track: int) -> dict:
    """Write the tracks' boxes of the tune frames as a labels file; return its frames."""
    d = read_boxes_csv(boxes_csv)
    if d.track_id is None:
        raise SystemExit(f"{boxes_csv}: no track ids (a video's boxes from `detect` have them)")
    ids, counts = np.unique(d.track_id, return_counts=True)
    long_enough = set(ids[counts >= min_track].tolist()) - {-1}
    frames: dict[str, dict] = {}
    for box, track, f in zip(d.xyxy.tolist(), d.track_id.tolist(), d.frame.tolist()):
        if track in long_enough and f % stride == 0 and any(a <= f <= b for a, b in TUNE):
            frames.setdefault(str(f), {"cars": [], "ignore": []})["cars"].append(box)
    frames = dict(sorted(frames.items(), key=lambda kv: int(kv[0])))
    out.write_text(json.dumps({"video": str(video), "camera": "highway_dashcam",
                               "format": "pseudo-labels: a model's own tracks (tools/self_training.py)", "frames": frames}))
    return frames


def agreement(frames: dict, label_files: list[Path]) -> str:
    """How the pseudo-labels of labelled frames score against the labels, as ``evaluate`` matches them."""
    truth = {}
    for path in label_files:
        truth.update(load_annotations(path).frames)
    n = cars = ignored = 0
    for key, value in frames.items():
        if int(key) in truth:
            match = match_frame(value["cars"], truth[int(key)])
            n, cars, ignored = n + len(value["cars"]), cars + match.tp, ignored + match.ignored
    return f"{n} on labelled frames: {cars} a labelled car (IoU >= 0.5), {ignored} on an ignore region"


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data-dir", type=lambda p: Path(p).resolve(), default=REPO.parent / "shared" / "data", help="the training archives and the videos")
    ap.add_argument("--negatives", type=lambda p: Path(p).resolve(), default=REPO / "data" / "negatives", help="the mined negatives")
    ap.add_argument("--rounds", type=int, nargs="+", default=[10, 40], metavar="MIN_TRACK",
                    help="each round's minimum track length in frames (default: 10 40)")
    ap.add_argument("--stride", type=int, default=7, help="every STRIDE-th tune frame gives pseudo-labels (default 7)")
    args = ap.parse_args(argv)
    video = args.data_dir / VIDEO
    if not video.is_file():
        raise SystemExit(f"{video}: not found (the highway dashcam clip is in ../shared/data only)")
    labels, sources = CAMERAS["project tune"]
    train = ["train", "--data-dir", str(args.data_dir), *negatives_options(args.negatives, sources), "--overwrite"]
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        model = tmp / "round0.npz"
        cli(*train, "--labels", *map(str, labels), "--model", str(model))
        for scored, files in GROUPS.items():
            print(f"round 0 (no dashcam data)        {scored:13s} {evaluate(files, model)}", flush=True)
        for k, min_track in enumerate(args.rounds, 1):
            boxes, pseudo = tmp / f"boxes{k}.csv", tmp / f"pseudo{k}.json"
            cli("detect", str(video), "--model", str(model), "--boxes", str(boxes), "--no-video", "--no-progress", "--overwrite")
            frames = pseudo_labels(boxes, video, pseudo, stride=args.stride, min_track=min_track)
            n = sum(len(v["cars"]) for v in frames.values())
            print(f"round {k}: {n} pseudo-labels on {len(frames)} frames (tracks >= {min_track} frames); "
                  f"{agreement(frames, GROUPS['highway tune'])}", flush=True)
            model = tmp / f"round{k}.npz"
            cli(*train, "--labels", *map(str, labels), str(pseudo), "--model", str(model))
            for scored, files in GROUPS.items():
                print(f"round {k} (tracks >= {min_track:3d} frames)  {scored:13s} {evaluate(files, model)}", flush=True)


if __name__ == "__main__":
    main()
