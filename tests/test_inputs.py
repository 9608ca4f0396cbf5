"""One input, every option: ``detect`` with one input and in a batch run the same per-input runner.

Each option of ``detect`` that applies to an input is run twice on the same clip: alone, and in
a batch of two inputs; the tables written for the clip must be byte-identical. The camera used
here is made up (no lens distortion, a road plane for the test video's size), so that nothing
depends on the shared data.
"""

from __future__ import annotations

import shutil
import warnings
from importlib.util import find_spec
from pathlib import Path

import numpy as np
import pytest

import vehicle_detection as vd
from vehicle_detection.cli import main
from vehicle_detection.errors import InputError, OutputError, UsageError
from vehicle_detection.io.tables import read_boxes_csv
from vehicle_detection.io.video import probe_video, read_frames
from vehicle_detection.pipeline.inputs import InputOptions, Outputs, default_outputs, run_input

REPO = Path(__file__).resolve().parents[1]
TEST_VIDEO = REPO / "test_video.mp4"
TEST_IMAGES = REPO / "test_images"

pytestmark = [
    pytest.mark.skipif(not (TEST_VIDEO.is_file() and (TEST_IMAGES / "test1.jpg").is_file()), reason="test_video.mp4 or test_images/ not in the checkout"),
    pytest.mark.xdist_group(name="test_inputs"),  # one worker: the runs of `detect` below are shared by several tests
]


def flat_camera() -> vd.Camera:
    """A 1280x720 camera without distortion whose road plane is a plausible one of the test video."""
    birds_eye = vd.BirdsEye(
        src=[[190, 720], [585, 455], [698, 455], [1130, 720]], dst=[[320, 720], [320, 0], [960, 0], [960, 720]],
        image_size=(1280, 720), warped_size=(1280, 720), xm_per_px=3.7 / 640, ym_per_px=30 / 720,
    )
    matrix = [[1000.0, 0.0, 640.0], [0.0, 1000.0, 360.0], [0.0, 0.0, 1.0]]
    return vd.Camera(image_size=(1280, 720), matrix=matrix, distortion=[0.0] * 5, birds_eye=birds_eye)


@pytest.fixture(scope="module")
def clips(tmp_path_factory) -> Path:
    """The test video's first 5 frames (``v.mp4``, boxes in every frame), its first 2 (``w.mp4``, the other
    input of the batches: only ``v``'s tables are compared; 2 frames, of which ``--start 1`` leaves one), and the camera file."""
    d = tmp_path_factory.mktemp("clips")
    fps = probe_video(TEST_VIDEO).fps
    with vd.VideoWriter(d / "v.mp4", fps, (1280, 720), crf=18) as v, vd.VideoWriter(d / "w.mp4", fps, (1280, 720), crf=18) as w:
        for i, frame in enumerate(read_frames(TEST_VIDEO)):
            if i == 5:
                break
            v.write(frame)
            if i < 2:
                w.write(frame)
    flat_camera().save(d / "camera.json")
    return d


@pytest.fixture(scope="module")
def detect(clips, tmp_path_factory):
    """``detect(*inputs_and_options)``: the folder ``detect ... --out-dir FOLDER --no-progress`` wrote into,
    run once per module for the same arguments (several tests look at the same run; none writes into it)."""
    runs: dict[tuple[str, ...], Path] = {}

    def run(*argv) -> Path:
        key = tuple(str(a) for a in argv)
        if key not in runs:
            out = tmp_path_factory.mktemp("run") / "out"
            assert main(["detect", *key, "--out-dir", str(out), "--no-progress"]) == 0
            runs[key] = out
        return runs[key]

    return run


def _tables(folder: Path, stem: str) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.glob(f"{stem}_*")) if p.suffix != ".mp4"}


# --no-video alone is in "full-search-every", "lanes-from-footage", "report" and "horizon"; --camera alone,
# in "formats" (which checks its distances too).
OPTIONS = {
    "plain": [],
    "formats": ["--format", "csv,mot,lanes", "--camera", "{camera}"],
    "start-end": ["--start", "1", "--end", "4"],  # 3 frames (in 2, no track is confirmed)
    "frames": ["--frames", "1-3"],
    "full-search-every": ["--full-search-every", "3", "--no-video"],
    "lanes": ["--lanes", "--camera", "{camera}"],
    "lanes-from-footage": ["--lanes", "--format", "csv,lanes", "--no-video"],
    "report": ["--report", "--no-video"],
    "preset-crf": ["--preset", "veryfast", "--crf", "30"],
    "horizon": ["--horizon", "plan", "--no-video"],
}


@pytest.mark.parametrize("name", list(OPTIONS))
def test_an_option_does_the_same_alone_and_in_a_batch(clips, detect, name):
    opts = [o.format(camera=clips / "camera.json") for o in OPTIONS[name]]
    alone, batch = detect(clips / "v.mp4", *opts), detect(clips / "v.mp4", clips / "w.mp4", *opts)
    written = _tables(alone, "v")
    assert written and written == _tables(batch, "v")
    assert (alone / "v_detected.mp4").exists() is ("--no-video" not in opts)
    assert (batch / "v_detected.mp4").exists() is ("--no-video" not in opts)
    table = read_boxes_csv(alone / "v_boxes.csv")
    if "--camera" in opts:
        assert "distance_m" in table.data
    frames = set(table.frame.tolist())
    lo, hi = {"start-end": (1, 3), "frames": (1, 3)}.get(name, (0, 4))
    assert frames and min(frames) >= lo and max(frames) <= hi


def test_the_boxes_alone_without_the_video_are_those_of_the_run_with_it(clips, detect, tmp_path):
    """``detect V --boxes B --no-video`` writes only B, with the boxes of the run that writes the video."""
    only = tmp_path / "only"
    only.mkdir()
    assert main(["detect", str(clips / "v.mp4"), "--boxes", str(only / "B.csv"), "--no-video", "--no-progress"]) == 0
    assert sorted(p.name for p in only.iterdir()) == ["B.csv"]
    full = detect(clips / "v.mp4")
    assert (full / "v_detected.mp4").is_file() and (only / "B.csv").read_bytes() == (full / "v_boxes.csv").read_bytes()
    assert sorted(p.name for p in clips.iterdir()) == ["camera.json", "v.mp4", "w.mp4"]  # nothing beside the input


def test_a_batch_with_lanes_and_a_camera(clips, detect):
    """``detect A.mp4 B.mp4 --out-dir o --lanes --camera C.json`` draws the lanes of each input."""
    out = detect(clips / "v.mp4", clips / "w.mp4", "--lanes", "--camera", clips / "camera.json")
    assert sorted(p.name for p in out.iterdir()) == ["v_boxes.csv", "v_detected.mp4", "w_boxes.csv", "w_detected.mp4"]
    plain = detect(clips / "v.mp4")
    with_lanes = next(read_frames(out / "v_detected.mp4")).astype(int)
    without = next(read_frames(plain / "v_detected.mp4")).astype(int)
    assert np.abs(with_lanes - without).max() > 100  # the lane (or "lane: not found") is drawn


@pytest.mark.skipif(find_spec("matplotlib") is None, reason='matplotlib not installed (pip install "vehicle-detection[report]")')
def test_a_batch_writes_each_input_s_report(clips, detect):
    """``detect A B --out-dir o --report`` writes each input's report into o; without --lanes, no Lanes section."""
    batch = detect(clips / "v.mp4", clips / "w.mp4", "--report", "--no-video")
    assert sorted(p.name for p in batch.iterdir()) == ["v_boxes.csv", "v_report.html", "w_boxes.csv", "w_report.html"]
    page = (batch / "v_report.html").read_text()
    assert "<h2>Track timeline</h2>" in page and "<h2>Lanes</h2>" not in page


def test_names_of_one_input_are_refused_in_a_batch(clips, tmp_path, capsys):
    for option in (["--lanes-csv", "l.csv"], ["--boxes", "b.csv"], ["--out", "o.mp4"]):
        assert main(["detect", str(clips / "v.mp4"), str(clips / "w.mp4"), "--out-dir", str(tmp_path), *option]) == 2
        assert "name the outputs of one input" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_out_with_no_video_is_refused(clips, tmp_path, capsys):
    assert main(["detect", str(clips / "v.mp4"), "--out", str(tmp_path / "o.mp4"), "--no-video"]) == 2
    assert "--no-video writes none" in capsys.readouterr().err


def test_images_alone_and_in_a_batch(tmp_path):
    folder = tmp_path / "shots"
    folder.mkdir()
    for name in ("test1.jpg", "test4.jpg"):
        shutil.copyfile(TEST_IMAGES / name, folder / name)
    alone, batch = tmp_path / "alone", tmp_path / "batch"
    opts = ["--format", "csv,coco,mot", "--no-progress"]
    assert main(["detect", str(folder), "--out-dir", str(alone), *opts]) == 0
    assert main(["detect", str(folder), str(TEST_IMAGES / "test5.jpg"), "--out-dir", str(batch), *opts]) == 0
    for f in ("shots_coco.json", "shots_mot.txt", "shots_detected/boxes.csv"):
        assert (alone / f).read_bytes() == (batch / f).read_bytes(), f
    assert sorted(p.name for p in (alone / "shots_detected").iterdir()) == ["boxes.csv", "test1.jpg", "test4.jpg"]
    # A single image of a batch goes into the batch's one COCO dataset of images, not a file of its own.
    assert (batch / "images_coco.json").is_file() and not (batch / "test5_coco.json").exists()


def test_detect_many_takes_a_detector_and_its_config(clips, tmp_path):
    """A DetectorConfig of one's own reaches every input of a batch."""
    base = vd.Detector()
    strict = vd.Detector(base.model, base.config.replace(image_threshold=base.config.image_threshold * 50))
    options = InputOptions(video=False, frames=(0, 4))
    shots = tmp_path / "shots"
    shots.mkdir()
    shutil.copyfile(TEST_IMAGES / "test1.jpg", shots / "test1.jpg")
    default = vd.detect_many([shots], tmp_path / "default", options)
    own = vd.detect_many([shots], tmp_path / "own", options, detector=strict)
    assert default[0].n_boxes > 0 and own[0].n_boxes < default[0].n_boxes
    ref = vd.process_video(clips / "v.mp4", detector=strict, frames=(0, 4), progress=False)
    (result,) = vd.detect_many([clips / "v.mp4"], tmp_path / "video", options, detector=strict)
    assert result.n_boxes == len(ref) and result.n_frames == 4


def test_run_input_refuses_before_any_work(clips, tmp_path):
    video = clips / "v.mp4"
    same = Outputs(tmp_path / "x.mp4", {"csv": tmp_path / "x.mp4"})
    with pytest.raises(OutputError, match="the annotated output and the boxes CSV cannot be the same file"):
        run_input(video, outputs=same)
    with pytest.raises(OutputError, match="named for two outputs"):
        run_input(video, outputs=Outputs(None, {"csv": tmp_path / "t.txt", "mot": tmp_path / "t.txt"}))
    with pytest.raises(InputError, match="COCO JSON is written for images"):
        run_input(video, InputOptions(formats=("coco",)), out_dir=tmp_path)
    with pytest.raises(OutputError, match="output would overwrite the input"):
        run_input(video, InputOptions(inputs=(tmp_path / "v_boxes.csv",)), out_dir=tmp_path)
    with pytest.raises(UsageError, match="unknown table format"):
        InputOptions(formats=("xml",))
    assert list(tmp_path.iterdir()) == []


def test_default_outputs():
    out = default_outputs(Path("a/clip.mp4"), "video", None, ("csv", "lanes"), video=False)
    assert out == Outputs(None, {"csv": Path("a/clip_boxes.csv"), "lanes": Path("a/clip_lanes.csv")})
    folder = default_outputs(Path("a/shots"), "folder", Path("o"))
    assert folder.annotated == Path("o/shots_detected") and folder.tables == {"csv": Path("o/shots_detected/boxes.csv")}


def test_the_earlier_keywords_still_work_with_a_warning(clips, tmp_path):
    with pytest.warns(DeprecationWarning, match="process_video"):
        old = vd.process_video(clips / "v.mp4", boxes_csv=tmp_path / "old.csv", start=1, max_frames=3, progress=False)
    with warnings.catch_warnings():
        warnings.simplefilter("error", DeprecationWarning)
        new = vd.process_video(clips / "v.mp4", tables={"csv": tmp_path / "new.csv"}, frames=(1, 4), progress=False)
    assert old == new and (tmp_path / "old.csv").read_bytes() == (tmp_path / "new.csv").read_bytes()
    with pytest.warns(DeprecationWarning, match="detect_many"):
        (r,) = vd.detect_many([clips / "v.mp4"], tmp_path / "many", video=False, frames=(1, 4))
    assert (tmp_path / "many" / "v_boxes.csv").read_bytes() == (tmp_path / "new.csv").read_bytes() and r.n_frames == 3
