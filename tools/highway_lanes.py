"""Lanes and distances of one ``detect --lanes`` run, against the hand-checked frames of the highway clip.

    vehicle-detection detect ../shared/data/videos/highway_dashcam_854x480.mp4 --lanes \\
        --lanes-csv /tmp/L.csv --boxes /tmp/B.csv --out /tmp/o.mp4
    python tools/highway_lanes.py /tmp/L.csv [--boxes /tmp/B.csv [/tmp/B_other.csv ...]] [--visibility tools/highway_lane_visibility.csv] [--tracks 5]

Prints the frames with a lane drawn (a radius in the lanes CSV), out of all frames and out of the
hand-checked frames in which both lines of the camera's lane are visible, and, for the longest
approaching tracks of the first boxes CSV (cars that come closer by 5 m or more), the Spearman
rank correlation of ``distance_m`` with the frame number (-1: the distance falls from every frame
to the next), the largest change from one box to the next, the rises of more than 1 m and the
share of steps without change (a box bottom that stays on its pixel row), in each boxes CSV given (the same tracks: runs of one video with one model track alike, so the
distances of two versions of the code can be compared track by track).

**The hand-checked frames** (``tools/highway_lane_visibility.csv``, frame indexes only, no
pictures: the clip's licence is unknown): every 4th decoded frame of
``highway_dashcam_854x480.mp4`` (147 frames) was looked at, cropped to the road (rows 240 to 420)
with the ray from the vanishing point to the bottom centre of the frame (straight ahead of the
camera) drawn on it, and labelled

* ``both``: a lane line on each side of that ray, each with at least one dash clearly visible
  between the bonnet and the traffic ahead (the lane the camera is in, bounded on both sides);
* ``on_line``: a line's dashes lie within a tenth of the lane's width (about 0.4 m) of the ray:
  the car drives on a line or is crossing it, and "its lane" is not defined;
* ``hidden``: a line hidden, here by a car passing close on the left (frames 364 to 432);
* ``unclear``: one line too faint to tell under the windscreen's reflection.

The labels were made once by eye (section 4.6 of the writeup); they do not depend on the code.
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]


def lane_frames(path: Path) -> tuple[int, set[int]]:
    """``(frames in the lanes CSV, frames with a lane)``."""
    with open(path, newline="", encoding="utf-8-sig") as fh:
        rows = list(csv.DictReader(fh))
    radius = [k for k in rows[0] if k != "frame"][0] if rows else "curvature_m"
    return len(rows), {int(r["frame"]) for r in rows if r[radius] not in ("", None)}


def visibility(path: Path) -> dict[int, str]:
    with open(path, newline="", encoding="utf-8") as fh:
        return {int(r["frame"]): r["lines"] for r in csv.DictReader(fh)}


def track_table(boxes: Path) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """``track -> (frames, distance_m)`` of the tracked boxes with a distance, in frame order."""
    from vehicle_detection.io.tables import read_boxes_csv

    table = read_boxes_csv(boxes)
    dist = table.data.get("distance_m")
    if dist is None or table.track_id is None:
        return {}
    out = {}
    for t in np.unique(table.track_id[table.track_id >= 0]):
        sel = (table.track_id == t) & np.isfinite(dist)
        order = np.argsort(table.frame[sel], kind="stable")
        out[int(t)] = (table.frame[sel][order], dist[sel][order])
    return out


def approaching(tracks: dict, n: int) -> list[int]:
    """The ``n`` longest tracks that approach, longest first.

    A track approaches (as in ``tools/compare_road_estimate.py``) when it has at least 10 boxes
    with a distance and the mean distance of its first fifth exceeds that of its last fifth by 5 m
    or more.
    """
    keep = []
    for t, (_, d) in tracks.items():
        fifth = max(1, len(d) // 5)
        if len(d) >= 10 and d[:fifth].mean() - d[-fifth:].mean() >= 5:
            keep.append(t)
    return sorted(keep, key=lambda t: -len(tracks[t][1]))[:n]


def describe(t: int, fr: np.ndarray, d: np.ndarray) -> str:
    from scipy.stats import spearmanr

    steps = np.diff(d)
    return (f"track {t}: {len(d)} boxes, {d[0]:.1f} m -> {d[-1]:.1f} m, Spearman rho {spearmanr(fr, d)[0]:+.2f}, "
            f"largest change from one box to the next {np.abs(steps).max():.1f} m, rises above 1 m: {int(np.sum(steps > 1.0))}, "
            f"unchanged {np.mean(steps == 0):.0%} of steps")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("lanes_csv", type=Path)
    parser.add_argument("--boxes", type=Path, nargs="+", default=[], help="boxes CSVs with distances (the tracks are chosen in the first)")
    parser.add_argument("--visibility", type=Path, default=REPO / "tools" / "highway_lane_visibility.csv")
    parser.add_argument("--tracks", type=int, default=5)
    args = parser.parse_args(argv)
    n, drawn = lane_frames(args.lanes_csv)
    print(f"a lane drawn in {len(drawn)} of {n} frames")
    if args.visibility.is_file():
        vis = visibility(args.visibility)
        for label in ("both", "on_line", "hidden", "unclear"):
            frames = [f for f, v in vis.items() if v == label]
            if frames:
                got = sum(f in drawn for f in frames)
                print(f"  hand-checked '{label}': {len(frames)} frames, a lane drawn in {got} ({got / len(frames):.0%})")
    if args.boxes:
        tables = [track_table(b) for b in args.boxes]
        chosen = approaching(tables[0], args.tracks)
        print(f"the {len(chosen)} longest approaching tracks of {args.boxes[0]} (distance down by 5 m or more from their first "
              "to their last fifth):")
        for path, tracks in zip(args.boxes, tables):
            print(f"  {path}:")
            for t in chosen:
                print("    " + (describe(t, *tracks[t]) if t in tracks else f"track {t}: not in this run"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
