"""Aggregate throughput of ``vehicle-detection detect FOLDER`` with --jobs 1 and 2, with and without video.

Copies a video (default: the shipped test_video.mp4) several times into a temporary folder and runs
the command line on the folder, as a user would, in the same session for every configuration,
several rounds interleaved (the machine's speed drifts). Prints the range of aggregate frames per
second (all frames of all copies / wall time, process start-up and model load included) per
configuration.

    python benchmarks/bench_many.py [--video V] [--copies 3] [--rounds 3]
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--video", default=str(REPO / "test_video.mp4"))
    ap.add_argument("--copies", type=int, default=3)
    ap.add_argument("--rounds", type=int, default=3)
    args = ap.parse_args()
    sys.path.insert(0, str(REPO))
    from vehicle_detection.io.video import probe_video

    n = probe_video(args.video).n_frames
    configs = [(1, False), (2, False), (1, True), (2, True)]
    fps: dict = {c: [] for c in configs}
    with tempfile.TemporaryDirectory() as tmp:
        src = Path(tmp) / "in"
        src.mkdir()
        for i in range(args.copies):
            shutil.copyfile(args.video, src / f"v{i}{Path(args.video).suffix}")
        # Warm the numba cache once, outside the timings.
        subprocess.run([sys.executable, "-m", "vehicle_detection.cli", "detect", args.video, "--no-video", "--frames", "0-1",
                        "--out-dir", str(Path(tmp) / "warm"), "--no-progress"], check=True, cwd=REPO, capture_output=True)
        for r in range(args.rounds):
            for jobs, no_video in configs:
                out = Path(tmp) / f"out{r}_{jobs}_{int(no_video)}"
                cmd = [sys.executable, "-m", "vehicle_detection.cli", "detect", str(src), "--out-dir", str(out), "--jobs", str(jobs), "--no-progress"]
                if no_video:
                    cmd.append("--no-video")
                t = time.perf_counter()
                subprocess.run(cmd, check=True, cwd=REPO, capture_output=True)
                fps[(jobs, no_video)].append(n * args.copies / (time.perf_counter() - t))
    print(f"{args.copies} copies of {Path(args.video).name} ({n} frames each), {args.rounds} rounds; aggregate frames/s (min to max, median)")
    for (jobs, no_video), v in fps.items():
        v = sorted(v)
        print(f"  --jobs {jobs} {'--no-video' if no_video else 'with video':11}  {v[0]:6.1f} to {v[-1]:6.1f}  (median {v[len(v) // 2]:.1f})")


if __name__ == "__main__":
    main()
