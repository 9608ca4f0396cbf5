"""How much the tracked boxes' sides move from frame to frame, with and without the side fit.

    python tools/box_jitter.py VIDEO [VIDEO ...] [--frames N] [--rounds R]

For each video, the embedded model tracks the first N frames twice: with its settings as saved
(the boxes' sides fitted to the frame, ``DetectorConfig.side_fit``) and with ``side_fit=None``.
For every track and every pair of consecutive frames it holds, the left and right sides' moves
are taken as shares of the box's width; the mean, median and 95th percentile are printed. A
steady car gives small moves; a fit that hops between two edges of one car gives large ones.

It also times :func:`vehicle_detection.refine.fit_sides` alone over the fitted run's boxes, each in
its own frame, ``R`` rounds (one thread): milliseconds a box and a frame.
"""

from __future__ import annotations

import argparse
import itertools
import time
from contextlib import closing
from pathlib import Path

import numpy as np


def side_moves(table) -> np.ndarray:
    """The left and right sides' moves between consecutive frames of each track, in box widths."""
    out = [np.zeros((0, 2))]
    for t in np.unique(table.track_id):
        rows = table[table.track_id == t]
        order = np.argsort(rows.frame)
        xy, frames = rows.xyxy[order].astype(np.float64), rows.frame[order]
        next_frame = np.diff(frames) == 1
        width = (xy[1:, 2] - xy[1:, 0])[next_frame]
        out.append(np.abs(np.diff(xy, axis=0))[next_frame][:, [0, 2]] / width[:, None])
    return np.concatenate(out)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("videos", nargs="+", type=Path)
    parser.add_argument("--frames", type=int, default=251, help="frames of each video (default 251)")
    parser.add_argument("--rounds", type=int, default=3, help="rounds of the fit's timing (default 3)")
    args = parser.parse_args(argv)

    import vehicle_detection as vd

    model = vd.load_default_model()
    for video in args.videos:
        with closing(vd.read_frames(video)) as decoded:
            frames = list(itertools.islice(decoded, args.frames))
        for name, fit in (("sides fitted", model.detector_config.side_fit), ("not fitted", None)):
            detector = vd.Detector(model.replace(detector_config=model.detector_config.replace(side_fit=fit)))
            table = vd.Detections.concatenate(found for _, found in detector.track_frames(frames))
            moves = side_moves(table)
            print(f"{video.name}, {len(frames)} frames, {name}: {len(table)} boxes; side move a frame, in box widths: "
                  f"mean {moves.mean():.4f}, median {np.median(moves):.4f}, 95th percentile {np.percentile(moves, 95):.4f}")
            if fit is not None and len(table):
                by_frame = [(frames[i], table.at_frame(i).xyxy) for i in range(len(frames))]
                for r in range(args.rounds):
                    t = time.perf_counter()
                    for frame, boxes in by_frame:
                        vd.fit_sides(frame, boxes, fit)
                    dt = time.perf_counter() - t
                    print(f"  fit_sides alone, round {r + 1}: {1e3 * dt / len(table):.3f} ms a box, {1e3 * dt / len(frames):.3f} ms a frame")


if __name__ == "__main__":
    main()
