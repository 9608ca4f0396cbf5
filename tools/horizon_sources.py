"""The horizon each source gives, clip by clip: the road's lines and the cars (writeup 3.4, "The horizon from the cars").

    python tools/horizon_sources.py [OC_DIR]

For the first 12 frames of each dev clip (and of each shot of the highway dashcam clip, when
``../shared/data`` has it), and of each simulated view in ``OC_DIR`` (written by
``tools/other_cameras.py``), prints the horizon :func:`vehicle_detection.estimate_horizon` reads
off the road's lines (inside black bars, dark footage brightened, as the detector reads them)
and the one the embedded detector reads off the cars
(:meth:`Detector._horizon_from_cars`, the fallback where the lines give none), as fractions of
the picture height, and the seconds the cars took.
"""

from __future__ import annotations

import itertools
import sys
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


def main() -> None:
    import vehicle_detection as vd
    from vehicle_detection.exposure import brighten
    from vehicle_detection.horizon import estimate_horizon

    detector = vd.Detector()
    oc_dir = Path(sys.argv[1]) if len(sys.argv) > 1 else None
    print(f"{'footage':40s} {'lines':>7s} {'cars':>7s}  seconds (cars)")
    for name, path, start in clips(oc_dir):
        frames = list(itertools.islice(vd.read_frames(path), start, start + 12))
        state = detector.new_tracker().state
        bars_and_light = vd.Detector(config=detector.config.replace(auto_horizon=False))
        bars_and_light._measure(frames, state, 2)  # as a video's start measures them, the horizon aside
        t = time.perf_counter()
        cars = detector._horizon_from_cars(frames, state, 2)
        seconds = time.perf_counter() - t
        pictures = [brighten(p, state.gain) for p in detector._pictures(frames, state)]
        lines = estimate_horizon(pictures, min_frames=3)  # as the detector reads them: inside the bars, brightened
        show = lambda v: "none" if v is None else f"{v:.3f}"  # noqa: E731
        print(f"{name:40s} {show(lines):>7s} {show(cars):>7s}  {seconds:.2f}", flush=True)


if __name__ == "__main__":
    main()
