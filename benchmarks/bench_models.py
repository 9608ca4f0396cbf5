"""The command line end to end with two models, alternately, in one run.

    python benchmarks/bench_models.py [VIDEO] [--models svm convnet] [--pairs 3]

Runs ``vehicle-detection detect VIDEO --model M`` for each model in turn, ``--pairs`` times
(A B, then B A, ...: the order alternates so that a drift of the machine's speed falls on both),
each a whole process (start, decode, search, tracking, drawing, encoding), and prints each run's
frames per second, each model's median and range, and the ratio of the second to the first pair
by pair. VIDEO defaults to ../shared/data/videos/project_video_clip_A.mp4 when present, else the
committed test_video.mp4. The compiled kernels are warmed by one untimed run of each model first.
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import tempfile
import time
from pathlib import Path

import av

ROOT = Path(__file__).resolve().parents[1]


def frames_of(video: Path) -> int:
    with av.open(str(video)) as c:
        return sum(1 for _ in c.decode(video=0))


def run_once(video: Path, model: str, out: Path) -> float:
    t = time.perf_counter()
    subprocess.run(["vehicle-detection", "detect", str(video), "--model", model, "--out", str(out / "o.mp4"),
                    "--boxes", str(out / "b.csv"), "--overwrite", "--no-progress"], check=True, capture_output=True)
    return time.perf_counter() - t


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    default = ROOT.parent / "shared" / "data" / "videos" / "project_video_clip_A.mp4"
    ap.add_argument("video", nargs="?", default=str(default if default.exists() else ROOT / "test_video.mp4"))
    ap.add_argument("--models", nargs=2, default=["svm", "convnet"], metavar=("A", "B"))
    ap.add_argument("--pairs", type=int, default=3)
    args = ap.parse_args(argv)
    video = Path(args.video)
    n = frames_of(video)
    a, b = args.models
    fps = {a: [], b: []}
    ratios = []
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp)
        for m in (a, b):
            run_once(video, m, out)
        for k in range(args.pairs):
            order = (a, b) if k % 2 == 0 else (b, a)
            got = {m: n / run_once(video, m, out) for m in order}
            for m in order:
                fps[m].append(got[m])
            ratios.append(got[b] / got[a])
            print(f"pair {k + 1} ({order[0]} first): {a} {got[a]:.1f} fps, {b} {got[b]:.1f} fps, {b} / {a} {ratios[-1]:.2f}", flush=True)
    print(f"{video.name}, {n} frames, {args.pairs} pairs of whole runs:")
    for m in (a, b):
        print(f"  {m}: median {statistics.median(fps[m]):.1f} fps (range {min(fps[m]):.1f} to {max(fps[m]):.1f})")
    print(f"  {b} / {a}: median {statistics.median(ratios):.2f} (range {min(ratios):.2f} to {max(ratios):.2f})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
