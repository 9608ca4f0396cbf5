"""Detection speed on a 1280x720 clip, against a plain decode+encode of the same clip.

    python benchmarks/bench_detection.py [VIDEO] [--model M] [--frames N] [--camera CAMERA.json [--lanes]]
                                         [--full-search-every N]

VIDEO defaults to ../shared/data/videos/project_video_clip_A.mp4 when present, else the
committed test_video.mp4. Prints frames per second for:

* decode+encode, plain PyAV (the reference): a single loop that decodes every frame to RGB and
  encodes it to an H.264 file (libx264, ``ultrafast``, crf 23, as ``process_video`` does) with
  the same library the pipeline uses; no threads, no detection. The floor any video tool pays;
  measured in the same run as the rest;
* decode+encode, FFmpeg's own (the second reference): what ``ffmpeg -i VIDEO -c:v libx264
  -preset ultrafast`` does, in PyAV: threaded decoding (frame and slice threads), YUV frames
  straight to the threaded encoder, no RGB at all;
* decode+encode through :mod:`vehicle_detection.io.video` (``read_frames`` into ``VideoWriter``,
  same settings): its threads and queues against the plain loop;
* detection only: the detector and tracker over frames already in memory;
* end to end: decode, detect, track, draw and encode to a file (``process_video``);
* end to end with a light search (one band of 256-pixel windows, every 4 cells: a few hundred
  windows a frame), 3 times: the pipeline around the search nearly on its own, against the
  references;

and the ratio of end-to-end to both references; with each, the CPU time a frame of all the
process's threads (less disturbed by other work on the machine than the wall time), and the
cost of the pipeline around the search: end to end less detection only. Then end to end once more with a
:class:`~vehicle_detection.io.Timeline`, printed as a table: milliseconds a frame of each stage
in each thread (decode, conversion to RGB, search, tracking, drawing, conversion to YUV,
encoding) and of each thread's waits on its queues, on the wall clock and in CPU time. With ``--camera`` (a file from
``vehicle-detection calibrate``), also end to end with every frame undistorted, and with
``--lanes`` too, end to end with undistortion, lane finding and drawing, and distances
(``process_video(road=Road(camera, lanes=True))``), plus the cost of each step per frame. With
``--full-search-every N``, also detection only and end to end with the search schedule
(:attr:`SearchPlan.full_search_every`), against every frame searched whole, in the same run.
"""

from __future__ import annotations

import argparse
import collections
import dataclasses
import inspect
import itertools
import os
import tempfile
import time
from fractions import Fraction
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def _default_video() -> Path:
    shared = Path(os.environ.get("VEHICLE_DETECTION_DATA", REPO.parent / "shared" / "data"))
    clip = shared / "videos" / "project_video_clip_A.mp4"
    return clip if clip.is_file() else REPO / "test_video.mp4"


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("video", nargs="?", default=None)
    ap.add_argument("--model", default=None, help="model file (default: the embedded model)")
    ap.add_argument("--frames", type=int, default=None, help="use only the first N frames")
    ap.add_argument("--camera", default=None, help="camera file: also time end to end with undistortion")
    ap.add_argument("--lanes", action="store_true", help="with --camera: also time end to end with lanes and distances")
    ap.add_argument("--full-search-every", type=int, default=None, metavar="N",
                    help="also time detection and end to end with the search schedule (whole frames every N frames)")
    args = ap.parse_args()
    if args.lanes and not args.camera:
        ap.error("--lanes needs --camera CAMERA.json (with a bird's-eye transform)")

    from vehicle_detection.classifier import VehicleClassifier
    from vehicle_detection.detector import Detector
    from vehicle_detection.pipeline import process_video
    from vehicle_detection.road.survey import Road
    from vehicle_detection.search import SearchScale
    try:
        from vehicle_detection.io.timeline import Timeline
    except ImportError:  # an older checkout
        Timeline = None
    from vehicle_detection.io.video import VideoWriter, probe_video, read_frames

    video = Path(args.video) if args.video else _default_video()
    info = probe_video(video)
    detector = Detector(VehicleClassifier.load(args.model)) if args.model else Detector()
    frames = list(itertools.islice(read_frames(video), args.frames))
    n = len(frames)
    detector.step(frames[0], detector.new_tracker())  # compile outside the timing
    print(f"{video.name}: {info.width}x{info.height}, {n} frames, {os.cpu_count()} cores")

    with tempfile.TemporaryDirectory() as tmp:
        plain_fps, plain_cpu = _rate(n, plain_decode_encode, video, Path(tmp) / "plain.mp4", n)
        ffmpeg_fps, ffmpeg_cpu = _rate(n, ffmpeg_decode_encode, video, Path(tmp) / "ffmpeg.mp4", n)

        def copy():
            with VideoWriter(Path(tmp) / "copy.mp4", info.fps, info.size, preset="ultrafast") as w:
                for f in itertools.islice(read_frames(video), n):
                    w.write(f)

        copy_fps, copy_cpu = _rate(n, copy)
        detect_fps, detect_cpu = _rate(n, lambda: collections.deque(detector.track(frames), maxlen=0))
        e2e_fps, e2e_cpu = _rate(n, process_video, video, Path(tmp) / "out.mp4", detector=detector, progress=False, frames=(0, n))

        # The pipeline around the search on its own: end to end with a search of a few hundred
        # windows (one band of 256-pixel windows, every 4 cells), the rest as it is.
        cfg = detector.config
        light_plan = dataclasses.replace(cfg.plan, scales=(SearchScale(4.0, 336, 720, step=4),))
        light = Detector(detector.model.replace(detector_config=cfg.replace(plan=light_plan)))
        light_fps, light_cpu = zip(*(
            _rate(n, process_video, video, Path(tmp) / "light.mp4", detector=light, progress=False, frames=(0, n), overwrite=True)
            for _ in range(3)
        ))

        timeline = None
        if "timeline" in inspect.signature(process_video).parameters:  # not in older checkouts
            timeline = Timeline()
            process_video(video, Path(tmp) / "timed.mp4", detector=detector, progress=False, frames=(0, n),
                          timeline=timeline)

        extra = []
        if args.full_search_every:
            plan = dataclasses.replace(cfg.plan, full_search_every=args.full_search_every)
            scheduled = Detector(detector.model.replace(detector_config=cfg.replace(plan=plan)))
            t = time.perf_counter()
            for _ in scheduled.track(frames):
                pass
            fps = n / (time.perf_counter() - t)
            extra.append(f"detection only, whole frames every {args.full_search_every}: {fps:7.1f} fps   "
                         f"= {fps / detect_fps:.2f} x every frame")
            t = time.perf_counter()
            process_video(video, Path(tmp) / "sched.mp4", detector=scheduled, progress=False, frames=(0, n))
            fps = n / (time.perf_counter() - t)
            extra.append(f"end to end, whole frames every {args.full_search_every}: {fps:7.1f} fps   "
                         f"= {fps / e2e_fps:.2f} x every frame, {fps / plain_fps:.2f} x plain decode+encode")
        if args.camera:
            from vehicle_detection.road.camera import Camera

            camera = Camera.load(args.camera)
            t = time.perf_counter()
            undistorted = [camera.undistort(f) for f in frames]
            extra.append(f"undistort (remap) alone        : {1000 * (time.perf_counter() - t) / n:6.2f} ms/frame")
            if args.lanes:
                from vehicle_detection.road.lanes import LaneTracker

                tracker = LaneTracker(camera.birds_eye)
                t = time.perf_counter()
                for f in undistorted:
                    tracker.step(f)
                extra.append(f"lane finding alone (warp, threshold, fit): {1000 * (time.perf_counter() - t) / n:6.2f} ms/frame")
            del undistorted
            t = time.perf_counter()
            process_video(video, Path(tmp) / "cam.mp4", detector=detector, progress=False, frames=(0, n), road=Road(camera))
            extra.append(f"end to end, undistorted        : {n / (time.perf_counter() - t):7.1f} fps")
            if args.lanes:
                t = time.perf_counter()
                process_video(video, Path(tmp) / "lanes.mp4", detector=detector, progress=False, frames=(0, n),
                              road=Road(camera, lanes=True), tables={"lanes": Path(tmp) / "lanes.csv"})
                extra.append(f"end to end, undistorted + lanes + distances: {n / (time.perf_counter() - t):7.1f} fps")

    print("(cpu: milliseconds of CPU a frame, all threads of this process)")
    print(f"decode+encode, plain PyAV (reference)    : {plain_fps:7.1f} fps   cpu {plain_cpu:6.1f} ms")
    print(f"decode+encode, FFmpeg's own (threaded, no RGB; 2nd reference): {ffmpeg_fps:7.1f} fps   cpu {ffmpeg_cpu:6.1f} ms")
    print(f"decode+encode, vehicle_detection.io.video: {copy_fps:7.1f} fps   cpu {copy_cpu:6.1f} ms")
    print(f"detection only (in memory): {detect_fps:7.1f} fps   ({1000 / detect_fps:.1f} ms/frame)   cpu {detect_cpu:6.1f} ms")
    print(f"end to end (decode, detect, track, draw, encode): {e2e_fps:7.1f} fps   "
          f"= {e2e_fps / plain_fps:.2f} x plain decode+encode, {e2e_fps / ffmpeg_fps:.2f} x FFmpeg's own   "
          f"cpu {e2e_cpu:6.1f} ms")
    print(f"end to end, light search (one band, ~{light.config.plan.scales[0].scale * 64:.0f}-px windows every 4 cells), "
          f"3 runs: {_range(light_fps)} fps = {_range([f / plain_fps for f in light_fps], '{:.2f}')} x plain decode+encode, "
          f"{_range([f / ffmpeg_fps for f in light_fps], '{:.2f}')} x FFmpeg's own   cpu {_range(light_cpu)} ms")
    print(f"the pipeline around the search (end to end - detection only): {1000 / e2e_fps - 1000 / detect_fps:6.1f} ms "
          f"wall, {e2e_cpu - detect_cpu:6.1f} ms cpu a frame")
    for line in extra:
        print(line)
    if timeline is None:
        print("\n(no Timeline in this checkout: no table of stages)")
        return
    print(f"\ntimeline of end to end (another run, {timeline.frames / timeline.wall:.1f} fps; stages of threads that "
          "overlap add up to more than the wall time):")
    print(timeline.table())


def _rate(n: int, work, *args, **kwargs) -> tuple[float, float]:
    """``work(*args, **kwargs)`` over ``n`` frames: frames a second (wall), and milliseconds of
    CPU a frame (all threads of this process)."""
    t, c = time.perf_counter(), time.process_time()
    work(*args, **kwargs)
    return n / (time.perf_counter() - t), 1000 * (time.process_time() - c) / n


def _range(xs: list[float], fmt: str = "{:.1f}") -> str:
    """min / median / max."""
    xs = sorted(xs)
    return "/".join(fmt.format(x) for x in (xs[0], xs[len(xs) // 2], xs[-1]))


def plain_decode_encode(src: Path, dest: Path, n: int | None = None) -> int:
    """Decode (the first ``n``) frames of ``src`` to RGB arrays and encode them to ``dest``
    (libx264 ``ultrafast``, crf 23), in one plain loop; returns the frames done."""
    import av

    done = 0
    with av.open(str(src)) as inp, av.open(str(dest), "w", format="mp4") as out:
        ist = inp.streams.video[0]
        ost = out.add_stream("libx264", rate=ist.average_rate, options={"preset": "ultrafast", "crf": "23"})
        ost.width, ost.height, ost.pix_fmt = ist.codec_context.width, ist.codec_context.height, "yuv420p"
        for frame in inp.decode(ist):
            if n is not None and done >= n:
                break
            rgb = frame.to_ndarray(format="rgb24")
            out.mux(ost.encode(av.VideoFrame.from_ndarray(rgb, format="rgb24")))
            done += 1
        out.mux(ost.encode(None))
    return done


def ffmpeg_decode_encode(src: Path, dest: Path, n: int | None = None) -> int:
    """FFmpeg's own transcode of (the first ``n``) frames of ``src`` to ``dest``, as
    ``ffmpeg -i SRC -an -c:v libx264 -preset ultrafast -crf 23 DEST`` does it, in PyAV: the
    decoder with frame and slice threads (``thread_type="AUTO"``, FFmpeg's thread count),
    decoded YUV frames straight into libx264 (its own threads), no RGB; returns the frames done."""
    import av
    from av.video.frame import PictureType

    done = 0
    with av.open(str(src)) as inp, av.open(str(dest), "w", format="mp4") as out:
        ist = inp.streams.video[0]
        ist.codec_context.thread_type, ist.codec_context.thread_count = "AUTO", 0
        rate = ist.codec_context.framerate or ist.guessed_rate or ist.average_rate  # the codec's (25): whole ticks
        ost = out.add_stream("libx264", rate=rate, options={"preset": "ultrafast", "crf": "23"})
        ost.width, ost.height, ost.pix_fmt = ist.codec_context.width, ist.codec_context.height, "yuv420p"
        ost.codec_context.thread_count = 0
        for frame in inp.decode(ist):
            if n is not None and done >= n:
                break
            if frame.format.name != "yuv420p":
                frame = frame.reformat(format="yuv420p")
            frame.pict_type = PictureType.NONE  # x264 chooses the key frames, as the ffmpeg command's does
            frame.pts, frame.time_base = done, 1 / Fraction(rate)  # a constant rate, as ffmpeg's mp4 output
            out.mux(ost.encode(frame))
            done += 1
        out.mux(ost.encode(None))
    return done


if __name__ == "__main__":
    main()
