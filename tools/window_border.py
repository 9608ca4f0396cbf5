"""What the search's ``window_border`` changes: margins on shipped frames, and search time (writeup 2.3).

    python tools/window_border.py [--rounds 3]

Scores every window of the embedded model's plan on the shipped test images and every 8th frame
of the test video twice: with ``window_border="frame"`` (a window's HOG sees the frame's gradient
across its border; the default) and ``"crop"`` (exactly its crop's features, as the training
patches have them). Prints the correlation of the two margins and their mean and median change,
over all windows and over the windows near the threshold (a crop margin above -1). Then times
the search alone (one thread, frames in memory) with each border, alternately, ``--rounds``
times over 40 frames of clip A (``../shared/data``, else the test video), and prints
milliseconds a frame (min to max) and the ratio of each round. With ``--steps``, also where the
``"frame"`` search's time goes: each step timed around its call (resizing the bands, colour
conversion, gamma, cells, blocks, colour sums, the two stages' products, the refinement), in
milliseconds a frame of each round.
"""

from __future__ import annotations

import argparse
import collections
import dataclasses
import os
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]


def _video_frames(path: Path, every: int, limit: int) -> list[np.ndarray]:
    from vehicle_detection.io.video import read_frames

    out = []
    for i, frame in enumerate(read_frames(path)):
        if i % every == 0:
            out.append(frame)
        if len(out) >= limit:
            break
    return out


def main(argv: list[str] | None = None) -> None:
    from vehicle_detection.classifier import load_default_model
    from vehicle_detection.io.images import read_image
    from vehicle_detection.search import search

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=3, help="alternated timing rounds (default 3)")
    ap.add_argument("--steps", action="store_true", help="also time each step of the 'frame' search")
    args = ap.parse_args(argv)

    model = load_default_model()
    plans = {b: dataclasses.replace(model.detector_config.plan, window_border=b) for b in ("frame", "crop")}
    shipped = [read_image(p) for p in sorted((REPO / "test_images").glob("*.jpg"))]
    shipped += _video_frames(REPO / "test_video.mp4", 8, 100)
    change, near, a_all, b_all = [], [], [], []
    for frame in shipped:
        a = search(frame, model, plans["frame"], all_windows=True).score
        b = search(frame, model, plans["crop"], all_windows=True).score
        change.append(a - b)
        near.append((a - b)[b > -1])
        a_all.append(a)
        b_all.append(b)
    change, near = np.concatenate(change), np.concatenate(near)
    corr = np.corrcoef(np.concatenate(a_all), np.concatenate(b_all))[0, 1]
    print(f"margins, 'frame' against 'crop', {len(change):,} windows of {len(shipped)} shipped frames: "
          f"correlation {corr:.4f}, change mean {change.mean():+.3f} median {np.median(change):+.3f} "
          f"(sd {change.std():.3f}); near the threshold (crop margin > -1, {len(near):,} windows): "
          f"mean {near.mean():+.3f} median {np.median(near):+.3f}", flush=True)

    data = Path(os.environ.get("VEHICLE_DETECTION_DATA", REPO.parent / "shared" / "data"))
    clip = data / "videos" / "project_video_clip_A.mp4"
    frames = _video_frames(clip if clip.is_file() else REPO / "test_video.mp4", 5 if clip.is_file() else 1, 40)
    for plan in plans.values():  # compile and warm both paths
        search(frames[0], model, plan)
    ms = {b: [] for b in plans}
    for _ in range(args.rounds):
        for b, plan in plans.items():
            t = time.perf_counter()
            for frame in frames:
                search(frame, model, plan)
            ms[b].append(1000 * (time.perf_counter() - t) / len(frames))
    for b in plans:
        print(f"search alone, window_border={b!r}, {len(frames)} frames: {min(ms[b]):.1f} to {max(ms[b]):.1f} ms a frame "
              f"({args.rounds} rounds)")
    ratios = [f / c for f, c in zip(ms["frame"], ms["crop"])]
    print(f"ratio 'frame' / 'crop', round by round: {', '.join(f'{r:.2f}' for r in ratios)}")
    if args.steps:
        steps(model, plans["frame"], frames, args.rounds)


STEPS = {"_band": "resize", "convert_color": "colour conversion", "hog_input": "gamma", "_region_cells": "cells",
         "_block_map": "blocks", "_colour_sums": "colour sums", "_two_stage_margins": "two stages' products",
         "_refine_products": "refinement"}


def steps(model, plan, frames, rounds: int) -> None:
    """Milliseconds a frame of each step of the search, timed around its call in the search module
    (replaced for this process only)."""
    from vehicle_detection import search as S

    spent = collections.defaultdict(float)

    def timed(name, fn):
        def call(*a, **k):
            t = time.perf_counter()
            try:
                return fn(*a, **k)
            finally:
                spent[name] += time.perf_counter() - t
        return call

    saved = {name: getattr(S, name) for name in STEPS}
    for name, fn in saved.items():
        setattr(S, name, timed(name, fn))
    try:
        for r in range(rounds):
            spent.clear()
            t = time.perf_counter()
            for frame in frames:
                S.search(frame, model, plan)
            whole = 1000 * (time.perf_counter() - t) / len(frames)
            parts = ", ".join(f"{label} {1000 * spent[name] / len(frames):.2f}" for name, label in STEPS.items())
            print(f"round {r + 1}: {whole:.1f} ms a frame: {parts}")
    finally:
        for name, fn in saved.items():
            setattr(S, name, fn)


if __name__ == "__main__":
    main()
