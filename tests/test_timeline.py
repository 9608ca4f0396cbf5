"""Tests of vehicle_detection.io.timeline: the stages of a video run, filled from every thread,
and a run's outputs the same with and without it (and the same as drawn on copies)."""

from __future__ import annotations

import threading
import time

import av
import numpy as np
import pytest

from conftest import REPO
from vehicle_detection.detector import Detector
from vehicle_detection.io.timeline import STAGES, UNTIMED, Timeline, timing
from vehicle_detection.io.video import VideoWriter, probe_video, read_frames
from vehicle_detection.pipeline import process_video
from vehicle_detection.viz.drawing import draw_detections

TEST_VIDEO = REPO / "test_video.mp4"
N = 13  # frames of test_video.mp4 each run takes (the footage is measured on the first 12; one more)

needs_test_video = pytest.mark.skipif(not TEST_VIDEO.is_file(), reason="test_video.mp4 not in the checkout")


def _decoded(path) -> list[np.ndarray]:
    with av.open(str(path)) as c:
        return [f.to_ndarray(format="rgb24") for f in c.decode(video=0)]


def test_add_lap_and_table():
    timeline = Timeline()
    assert timeline.stages == [] and timeline.per_frame_ms() == {}
    timeline.add("encode", 0.002)
    timeline.add("decode", 0.001)
    timeline.add("decode", 0.003)
    t = Timeline.now()
    after = timeline.lap("draw", t)
    assert after.wall >= t.wall and after.cpu >= t.cpu
    timeline.add("mine", 0.5)
    assert timeline.stages == ["decode", "draw", "encode", "mine"]  # pipeline order, unknown ones last
    assert timeline.seconds("decode") == pytest.approx(0.004) and timeline.count("decode") == 2
    assert timeline.seconds("search") == 0.0 and timeline.count("search") == 0
    timeline.frames, timeline.wall = 2, 0.01
    ms = timeline.per_frame_ms()
    assert ms["decode"] == pytest.approx(2.0) and ms["encode"] == pytest.approx(1.0)
    table = timeline.table()
    assert table.splitlines()[0].split() == ["stage", "thread", "ms/frame", "%", "wall", "cpu", "ms"]
    assert "decoder" in table and "mine" in table and "(2 frames, 200.0 fps)" in table
    assert "process" not in table  # no process CPU time recorded: no lines for it
    assert "Timeline(frames=2" in repr(timeline)
    with pytest.raises(ValueError, match="'wall' or 'cpu'"):
        timeline.per_frame_ms("user")


def _busy(seconds: float) -> None:
    end = time.thread_time() + seconds
    while time.thread_time() < end:
        pass


def test_cpu_time_is_the_stage_threads_own():
    # A stage that sleeps takes wall time and almost no CPU time, even while another thread
    # computes (its CPU time is that thread's, not the process's); one that computes takes both.
    timeline = Timeline()
    other = threading.Thread(target=_busy, args=(0.2,))
    t = timeline.now()
    other.start()
    time.sleep(0.1)
    t = timeline.lap("encoder_wait", t)
    other.join()
    _busy(0.05)
    timeline.lap("search", t)
    assert timeline.seconds("encoder_wait") >= 0.1 and timeline.cpu_seconds("encoder_wait") < 0.04
    assert timeline.cpu_seconds("search") >= 0.05
    assert timeline.seconds("search") >= timeline.cpu_seconds("search") - 0.02  # CPU time never runs ahead of the wall
    timeline.frames, timeline.wall, timeline.cpu = 1, 0.2, 0.08
    cpu = timeline.per_frame_ms("cpu")
    assert set(cpu) == {"search", "encoder_wait"}
    lines = {line.split()[0]: line.split() for line in timeline.table().splitlines()}
    assert float(lines["search"][4]) == pytest.approx(cpu["search"], abs=0.01)
    assert float(lines["other"][2]) == pytest.approx(80.0 - sum(cpu.values()), abs=0.02)  # the codecs' threads, the rest
    assert float(lines["process"][2]) == pytest.approx(80.0) and "(0.40 cores busy)" in timeline.table()


def test_add_from_many_threads():
    timeline = Timeline()
    threads = [threading.Thread(target=lambda: [timeline.add("search", 1.0) for _ in range(1000)]) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert timeline.seconds("search") == 4000.0 and timeline.count("search") == 4000


def test_timed_adds_each_call_even_when_it_raises():
    timeline = Timeline()
    assert timeline.timed("track", lambda a, b=1: a + b)(1, b=2) == 3

    def fails():
        raise KeyError("x")

    with pytest.raises(KeyError):
        timeline.timed("track", fails)()
    assert timeline.count("track") == 2


def test_untimed_is_the_clock_of_a_run_without_a_timeline():
    timeline = Timeline()
    assert timing(timeline) is timeline and timing(None) is UNTIMED

    def work(a, b=1):
        return a + b

    assert UNTIMED.timed("search", work) is work  # the stage runs as it is, no wrapper
    assert UNTIMED.now() == (0.0, 0.0) and UNTIMED.lap("decode", UNTIMED.now()) == (0.0, 0.0)
    assert repr(UNTIMED) == "UNTIMED"
    with pytest.raises(AttributeError):
        UNTIMED.frames = 3  # it keeps nothing: a run cannot write its figures into it


@needs_test_video
def test_reader_and_writer_fill_their_stages(tmp_path):
    import media

    clip = media.copy_packets(TEST_VIDEO, tmp_path / "clip.mp4", max_frames=10)  # the test video's first 10 frames
    timeline = Timeline()
    info = probe_video(clip)
    with VideoWriter(tmp_path / "copy.mp4", info.fps, info.size, preset="ultrafast", timeline=timeline) as writer:
        for frame in read_frames(clip, timeline=timeline):
            writer.write(frame)
    counts = {s: timeline.count(s) for s in timeline.stages}
    assert counts == {"decode": 10, "to_rgb": 10, "decoder_wait": 10, "read_wait": 11,  # and the end marker
                      "write": 10, "write_wait": 10, "to_yuv": 10, "encode": 11, "encoder_wait": 11}  # and flushing
    assert all(timeline.seconds(s) >= 0 for s in counts)


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """test_video.mp4's first frames through process_video with a Timeline, without one, and the
    same run by hand: every frame drawn on a copy (with the boxes the run without one reported),
    the copy written."""
    tmp = tmp_path_factory.mktemp("timeline")
    detector = Detector()
    timeline = Timeline()
    timed = process_video(TEST_VIDEO, tmp / "timed.mp4", detector=detector, frames=(0, N), progress=False,
                          tables={"csv": tmp / "timed.csv"}, timeline=timeline)
    plain = process_video(TEST_VIDEO, tmp / "plain.mp4", detector=detector, frames=(0, N), progress=False,
                          tables={"csv": tmp / "plain.csv"})
    info = probe_video(TEST_VIDEO)
    frames = [f for _, f in zip(range(N), read_frames(TEST_VIDEO))]
    with VideoWriter(tmp / "copies.mp4", info.fps, info.size, preset="ultrafast") as writer:
        for index, frame in enumerate(frames):
            drawn = draw_detections(frame, plain[plain.frame == index])
            assert not np.shares_memory(drawn, frame)
            writer.write(drawn)  # copied again
    return tmp, timeline, timed, plain


@needs_test_video
def test_process_video_fills_every_stage(runs):
    _, timeline, *_ = runs
    assert timeline.frames == N and timeline.wall > 0
    expected = [s for s in STAGES if s != "prepare"]  # prepare: only with a camera
    assert timeline.stages == expected
    ms = timeline.per_frame_ms()
    assert all(ms[s] >= 0 for s in expected)
    assert all(timeline.count(s) >= N for s in ("decode", "to_rgb", "search", "track", "draw", "write", "to_yuv", "encode"))
    assert timeline.count("footage") == 1 and timeline.count("warmup") == 2  # compile; wait for the loading
    assert ms["search"] > 0 and ms["decode"] > 0 and ms["encode"] > 0
    cpu = timeline.per_frame_ms("cpu")
    assert cpu["search"] > 0 and all(cpu[s] >= 0 for s in expected)
    assert 0 < sum(timeline.cpu_seconds(s) for s in expected) <= timeline.cpu  # the process: every thread
    assert sum(timeline.seconds(s) for s in ("decode", "to_rgb", "decoder_wait")) <= timeline.wall * 1.05
    lines = timeline.table().splitlines()
    assert [line.split()[0] for line in lines[1:-3]] == expected
    assert [line.split()[0] for line in lines[-3:]] == ["other", "process", "wall"]


@needs_test_video
def test_outputs_are_identical_with_and_without_the_timeline(runs):
    tmp, _, timed, plain = runs
    assert (tmp / "timed.csv").read_bytes() == (tmp / "plain.csv").read_bytes()
    assert len(timed) == len(plain) and len(plain) > 0
    a, b = _decoded(tmp / "timed.mp4"), _decoded(tmp / "plain.mp4")
    assert len(a) == len(b) == N
    assert all(np.array_equal(x, y) for x, y in zip(a, b))


@needs_test_video
def test_frames_drawn_in_place_are_those_drawn_on_copies(runs):
    # process_video draws on the decoded frame and writes it without a copy: the same video as
    # drawing on a copy and writing a copy of that, frame for frame.
    tmp, *_ = runs
    a, b = _decoded(tmp / "plain.mp4"), _decoded(tmp / "copies.mp4")
    assert len(a) == len(b) == N
    assert all(np.array_equal(x, y) for x, y in zip(a, b))
