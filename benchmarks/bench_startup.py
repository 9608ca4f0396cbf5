"""Cold start, warm start, real time and memory of ``vehicle-detection detect``, end to end.

    python benchmarks/bench_startup.py [--runs N] [--long-loops 5] [--skip-long] [--skip-start] [--timeline]
                                       [--kernels] [-- EXTRA CLI ARGS]

Every figure is a whole command-line run in a subprocess (process start, imports, model loading,
kernel compilation or cache loading, decode, detect, track, draw, encode, CSV):

``python -m vehicle_detection.cli detect VIDEO --out TMP --boxes TMP --overwrite --no-progress``

The runs import a copy of this checkout's package with its bytecode compiled first, as the
README's ``python -m pip install .`` leaves an install (pip compiles the modules it installs).
A checkout run where Python writes no bytecode (``PYTHONDONTWRITEBYTECODE``, as in many
containers) compiles the package's modules from source at every start instead, about 0.2 s of
one core; ``--source`` measures that (the copy without bytecode, none written).

1. **cold**: the README's main job (``test_video.mp4``, 38 frames) with a fresh, empty
   ``NUMBA_CACHE_DIR``, so every numba kernel is compiled (a fresh install);
2. **warm**: the same job again with the cache the cold run filled;

   cold and warm alternate, ``--runs`` times each; min / median / max are printed;
3. **real time**: clip A (``dev_set/project_video_clip_A.mp4``, 1280x720) stream-copied 5 times
   (1,250 frames, made with PyAV, no re-encoding) through the CLI with a warm cache, against two
   references measured alternately with it in the same run: a plain decode + ``ultrafast``
   encode of the same clip in one PyAV loop (through RGB, no threads), and FFmpeg's own
   transcode, as ``ffmpeg -i CLIP -c:v libx264 -preset ultrafast`` does it (threaded decoder
   and encoder, YUV straight through; PyAV's codecs, so no ffmpeg binary is needed): frames per
   second of all three and the CLI's ratio to each;
4. **memory**: peak RSS of the CLI on 250 and on 1,250 frames of the looped clip (from
   ``os.wait4``, per child): it should not grow with the video's length;
5. with ``--timeline``, once more the long clip, through ``process_video`` in this process with
   a :class:`~vehicle_detection.io.Timeline` (no process start, kernels already loaded): where a
   frame's time goes, stage by stage and thread by thread, as a table, on the wall clock and in
   CPU time (each stage's thread; FFmpeg's and x264's threads, and the cores kept busy);
6. with ``--kernels``, ``--runs`` times: in a new process on one core with a fresh numba cache,
   numba's own start (a trivial kernel compiled first), then each search kernel's compile time
   as one search of a test image compiles it (numba's compile events), their total and the first
   search's time: what a fresh install's first run compiles, without the helper process.

Extra arguments after ``--`` are passed to every ``detect`` run (e.g. ``-- --model M``).
"""

from __future__ import annotations

import argparse
import compileall
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
CLIP_A = REPO / "dev_set" / "project_video_clip_A.mp4"
SHORT = REPO / "test_video.mp4"

sys.path[:0] = [str(REPO), str(REPO / "tests"), str(REPO / "benchmarks")]  # this checkout, as the children
from bench_detection import ffmpeg_decode_encode, plain_decode_encode  # noqa: E402  the references, shared
from media import copy_packets, decoded_count  # noqa: E402  the tests' helpers for made-up clips


#: Where the children import the package from (:func:`install_copy`); the checkout until then.
PACKAGE_ROOT = REPO
#: Whether the children may not write bytecode (``--source``).
NO_BYTECODE = False


def install_copy(tmp: Path, *, bytecode: bool) -> None:
    """Copy the checkout's package into ``tmp`` for the children to import, with its bytecode
    compiled as ``pip install .`` compiles it, or (``bytecode=False``) with none, and none written."""
    global PACKAGE_ROOT, NO_BYTECODE
    root = tmp / "site"
    shutil.copytree(REPO / "vehicle_detection", root / "vehicle_detection",
                    ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
    if bytecode and not compileall.compile_dir(root / "vehicle_detection", quiet=1):
        raise SystemExit(f"could not compile {root / 'vehicle_detection'}")
    PACKAGE_ROOT, NO_BYTECODE = root, not bytecode


def _env(cache: Path) -> dict:
    env = dict(os.environ)
    env["NUMBA_CACHE_DIR"] = str(cache)
    env["PYTHONPATH"] = os.pathsep.join([str(PACKAGE_ROOT)] + [p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p])
    if NO_BYTECODE:
        env["PYTHONDONTWRITEBYTECODE"] = "1"
    return env


def run_detect(video: Path, tmp: Path, cache: Path, extra: list[str]) -> tuple[float, int]:
    """Seconds and peak RSS (bytes) of one CLI ``detect`` run."""
    cmd = [sys.executable, "-m", "vehicle_detection.cli", "detect", str(video), "--out", str(tmp / "out.mp4"),
           "--boxes", str(tmp / "out.csv"), "--overwrite", "--no-progress", *extra]
    t = time.perf_counter()
    proc = subprocess.Popen(cmd, env=_env(cache), cwd=PACKAGE_ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(proc.pid, 0)
    seconds = time.perf_counter() - t
    proc.returncode = os.waitstatus_to_exitcode(status)
    err = proc.stderr.read().decode(errors="replace")
    proc.stderr.close()
    if proc.returncode != 0:
        raise SystemExit(f"detect failed ({proc.returncode}): {' '.join(cmd)}\n{err}")
    rss = usage.ru_maxrss * (1 if sys.platform == "darwin" else 1024)
    return seconds, rss


def _stats(xs: list[float], fmt: str = "{:.2f}") -> str:
    return f"min {fmt.format(min(xs))}  median {fmt.format(statistics.median(xs))}  max {fmt.format(max(xs))}"


def main():
    argv = sys.argv[1:]
    extra: list[str] = []
    if "--" in argv:
        i = argv.index("--")
        argv, extra = argv[:i], argv[i + 1 :]
    # the runs start in the package's copy: paths given relative to here are made absolute
    extra = [str(Path(a).resolve()) if not a.startswith("-") and Path(a).exists() else a for a in extra]
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=3, help="runs of each measurement (default 3)")
    ap.add_argument("--long-loops", type=int, default=5, help="times clip A is looped for the long clip (default 5)")
    ap.add_argument("--skip-long", action="store_true", help="cold and warm start only")
    ap.add_argument("--skip-start", action="store_true", help="real time and memory only")
    ap.add_argument("--timeline", action="store_true",
                    help="also time the long clip's stages (process_video with a Timeline, in this process)")
    ap.add_argument("--kernels", action="store_true",
                    help="only each search kernel's compile time, one core, fresh cache (--runs times)")
    ap.add_argument("--source", action="store_true",
                    help="the package's modules compiled from source at every start (no bytecode), "
                         "not as an install leaves them")
    args = ap.parse_args(argv)
    print(f"{os.cpu_count()} cores, python {sys.version.split()[0]}, extra args {extra or 'none'}, package "
          + ("compiled from source at every start" if args.source else "bytecode compiled first, as `pip install .` does"))
    with tempfile.TemporaryDirectory(prefix="bench-startup-") as tmp_name:
        tmp = Path(tmp_name)
        install_copy(tmp, bytecode=not args.source)
        if args.kernels:
            for _ in range(args.runs):
                print_kernel_compile_times()
            return
        if not args.skip_start:
            cold, warm = [], []
            for i in range(args.runs):
                cache = tmp / f"cache{i}"
                cache.mkdir()
                cold.append(run_detect(SHORT, tmp, cache, extra)[0])
                warm.append(run_detect(SHORT, tmp, cache, extra)[0])
                print(f"  run {i + 1}: cold {cold[-1]:.2f} s, warm {warm[-1]:.2f} s", flush=True)
            print(f"cold start, {SHORT.name} (fresh numba cache): {_stats(cold)} s   (goal <= 5 s)")
            print(f"warm start, {SHORT.name} (cache filled)     : {_stats(warm)} s   (goal <= 2.0 s)")
        if args.skip_long:
            return
        cache = tmp / "cache-long"
        cache.mkdir()
        run_detect(SHORT, tmp, cache, extra)  # fill the cache
        one = copy_packets(CLIP_A, tmp / "clip_A_x1.mp4", loops=1)
        long = copy_packets(CLIP_A, tmp / f"clip_A_x{args.long_loops}.mp4", loops=args.long_loops)
        n_one, n_long = decoded_count(one), decoded_count(long)
        e2e, plain, ffmpeg, ratio, ratio_ff, rss_one, rss_long = [], [], [], [], [], [], []
        for i in range(args.runs):
            t = time.perf_counter()
            plain_decode_encode(long, tmp / "plain.mp4")
            plain.append(n_long / (time.perf_counter() - t))
            seconds, rss = run_detect(long, tmp, cache, extra)
            e2e.append(n_long / seconds)
            rss_long.append(rss)
            t = time.perf_counter()
            ffmpeg_decode_encode(long, tmp / "ffmpeg.mp4")
            ffmpeg.append(n_long / (time.perf_counter() - t))
            ratio.append(e2e[-1] / plain[-1])
            ratio_ff.append(e2e[-1] / ffmpeg[-1])
            rss_one.append(run_detect(one, tmp, cache, extra)[1])
            print(f"  run {i + 1}: detect {e2e[-1]:.1f} fps, plain decode+encode {plain[-1]:.1f} fps (ratio "
                  f"{ratio[-1]:.2f}), FFmpeg's own {ffmpeg[-1]:.1f} fps (ratio {ratio_ff[-1]:.2f}); "
                  f"peak RSS {rss_one[-1] / 2**20:.0f} MiB ({n_one} frames), "
                  f"{rss_long[-1] / 2**20:.0f} MiB ({n_long} frames)", flush=True)
        print(f"end to end, CLI detect, {n_long} frames 1280x720 (process start included): {_stats(e2e, '{:.1f}')} fps"
              "   (goal >= 60)")
        print(f"plain decode + ultrafast encode, same clip, same run         : {_stats(plain, '{:.1f}')} fps")
        print(f"FFmpeg's own decode + ultrafast encode (threaded, no RGB)    : {_stats(ffmpeg, '{:.1f}')} fps")
        print(f"ratio end to end / plain decode+encode                       : {_stats(ratio)}")
        print(f"ratio end to end / FFmpeg's own decode+encode                : {_stats(ratio_ff)}")
        print(f"peak RSS, {n_one} frames : {_stats([r / 2**20 for r in rss_one], '{:.0f}')} MiB")
        print(f"peak RSS, {n_long} frames: {_stats([r / 2**20 for r in rss_long], '{:.0f}')} MiB")
        if args.timeline:
            print_timeline(long, tmp, cache)


_KERNEL_TIMES = """
import os, sys, time
if hasattr(os, "sched_setaffinity"):
    os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})  # one core: no helper process
import numpy as np
from numba import njit
from numba.core import event
t = time.perf_counter()
njit(lambda a: a.sum() + 1.0)(np.zeros(3))
print(f"numba's own start (a trivial kernel): {time.perf_counter() - t:.2f} s")
class Times(event.Listener):
    def __init__(self):
        self.start, self.done = {}, []
    def on_start(self, ev):
        self.start[id(ev.data["dispatcher"])] = (time.perf_counter(), len(self.start))
    def on_end(self, ev):
        t, depth = self.start.pop(id(ev.data["dispatcher"]))
        f = ev.data["dispatcher"].py_func
        if f.__module__.startswith("vehicle_detection"):
            self.done.append((f.__name__, time.perf_counter() - t, depth))
times = Times()
event.register("numba:compile", times)
import vehicle_detection as vd
from vehicle_detection.search import search
image, model = vd.read_image(sys.argv[1]), vd.load_default_model()
t = time.perf_counter()
search(image, model)
first = time.perf_counter() - t
for name, s, depth in times.done:
    print(f"  {'  ' * depth}{name:22s} {s:.2f} s")
print(f"first search (compiling included): {first:.2f} s; the kernels' compile times: "
      f"{sum(s for _, s, depth in times.done if depth == 0):.2f} s (an indented kernel is compiled inside the one below it)")
"""


def print_kernel_compile_times() -> None:
    """One fresh process on one core with an empty numba cache: each search kernel's compile time."""
    with tempfile.TemporaryDirectory(prefix="bench-kernels-") as cache:
        done = subprocess.run([sys.executable, "-c", _KERNEL_TIMES, str(REPO / "test_images" / "test1.jpg")],
                              env=_env(Path(cache)), cwd=PACKAGE_ROOT, capture_output=True, text=True)
    if done.returncode:
        raise SystemExit(f"kernel timing failed: {done.stderr[-2000:]}")
    print(done.stdout, end="", flush=True)


def print_timeline(video: Path, tmp: Path, cache: Path) -> None:
    """One run of ``video`` through ``process_video`` in this process, with a Timeline, printed."""
    os.environ["NUMBA_CACHE_DIR"] = str(cache)  # the kernels the CLI runs cached; before numba loads
    try:
        from vehicle_detection.io.timeline import Timeline
    except ImportError:
        print("\n(no Timeline in this checkout: no table of stages)")
        return
    from vehicle_detection.pipeline import process_video

    # This process imports the checkout, not the children's copy, whose kernels the cache holds:
    # its own are compiled and loaded on a short run first, so that the timed run loads none.
    process_video(SHORT, tmp / "timeline-warm.mp4", overwrite=True, progress=False)
    timeline = Timeline()
    process_video(video, tmp / "timeline.mp4", tables={"csv": tmp / "timeline.csv"}, overwrite=True, progress=False,
                  timeline=timeline)
    print(f"\ntimeline of {video.name} through process_video in this process ({timeline.frames / timeline.wall:.1f} fps; "
          "stages of threads that overlap add up to more than the wall time):")
    print(timeline.table())


if __name__ == "__main__":
    main()
