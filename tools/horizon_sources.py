"""The horizon each source gives, clip by clip: the road's lines and the cars (docs/experiments.md, "The horizon from the cars").

    python tools/horizon_sources.py [OC_DIR] [--margins M [M ...]]

For the first 12 frames of each dev clip (and of each shot of the highway dashcam clip, when
``../shared/data`` has it), and of each simulated view in ``OC_DIR`` (written by
``tools/other_cameras.py``), prints the horizon :func:`vehicle_detection.estimate_horizon` reads
off the road's lines (inside black bars, dark footage brightened, as the detector reads them)
and the one the embedded detector reads off the cars
(:meth:`Detector._horizon_from_cars`, the fallback where the lines give none), as fractions of
the picture height, and the seconds the cars took. ``--margins`` prints the cars' horizon for
each of those smallest window margins (:attr:`vehicle_detection.footage.horizon.CarHorizon.min_margin`)
instead of the embedded detector's.
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
HIGHWAY = REPO.parent / "shared" / "data" / "videos" / "highway_dashcam_854x480.mp4"


def clips(oc_dir: Path | None) -> list[tuple[str, Path, int]]:
    out = [("test video", REPO / "test_video.mp4", 0), ("clip A", REPO / "dev_set" / "project_video_clip_A.mp4", 0)]
    if HIGHWAY.exists():  # its shots: the first, the zoomed replay (cut at 363), the replay (cut at 434)
        out += [(f"highway dashcam from frame {s}", HIGHWAY, s) for s in (0, 363, 387, 399, 434)]
    if oc_dir is not None:
        out += [(p.stem, p, 0) for p in sorted(oc_dir.glob("*.mp4"))]
    return out


def show(value: float | None) -> str:
    return "none" if value is None else f"{value:.3f}"


def main() -> None:
    import vehicle_detection as vd
    from vehicle_detection.footage.exposure import brighten
    from vehicle_detection.footage.horizon import estimate_horizon

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("oc_dir", nargs="?", type=Path, help="the simulated views of tools/other_cameras.py")
    ap.add_argument("--margins", nargs="+", type=float, metavar="M", help="smallest margins of the windows that count (default: the embedded detector's)")
    args = ap.parse_args()
    detector = vd.Detector()
    rule = detector.config.car_horizon
    margins = args.margins or [rule.min_margin]
    detectors = [vd.Detector(config=detector.config.replace(car_horizon=dataclasses.replace(rule, min_margin=m))) for m in margins]
    print(f"{'footage':40s} {'lines':>7s} " + " ".join(f"{f'cars {m:g}':>9s}" for m in margins) + "  seconds (cars, each margin)")
    for name, path, start in clips(args.oc_dir):
        frames = list(itertools.islice(vd.read_frames(path), start, start + 12))
        state = detector.new_tracker().state
        bars_and_light = vd.Detector(config=detector.config.replace(auto_horizon=False))
        bars_and_light._measure(frames, state, 2)  # as a video's start measures them, the horizon aside
        cars, seconds = [], []
        for each in detectors:
            t = time.perf_counter()
            cars.append(each._horizon_from_cars(frames, state, 2))
            seconds.append(time.perf_counter() - t)
        pictures = [brighten(p, state.gain) for p in detector._pictures(frames, state)]
        lines = estimate_horizon(pictures, min_frames=3)  # as the detector reads them: inside the bars, brightened
        print(f"{name:40s} {show(lines):>7s} " + " ".join(f"{show(c):>9s}" for c in cars) + "  " + " ".join(f"{s:.2f}" for s in seconds), flush=True)


if __name__ == "__main__":
    main()
