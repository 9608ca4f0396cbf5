"""Where ``detect`` writes a run's outputs: one folder (the current one, --out-dir, or --out's), one name
(the input's, or --out's), explicit per-output flags winning; and the CLI's messages name its flags only."""

from __future__ import annotations

import shutil
from pathlib import Path

import media
import numpy as np
import pytest
from PIL import Image

from vehicle_detection.cli import main
from vehicle_detection.errors import OutputError, UsageError
from vehicle_detection.io import check_output_path
from vehicle_detection.pipeline.batch import detect_many
from vehicle_detection.pipeline.inputs import InputOptions

REPO = Path(__file__).resolve().parents[1]
TEST_VIDEO = REPO / "test_video.mp4"
ERROR = "vehicle-detection: error: "

needs_video = pytest.mark.skipif(not TEST_VIDEO.is_file(), reason="test_video.mp4 not in the checkout")


def run(capsys, *argv) -> tuple[int, list[str]]:
    code = main([str(a) for a in argv])
    return code, capsys.readouterr().err.splitlines()


def listing(folder: Path) -> list[str]:
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*") if p.is_file())


@pytest.fixture(scope="module")
def short_clip(tmp_path_factory) -> Path | None:
    """The first 8 frames of test_video.mp4 (packets copied): enough for a road plane (5 frames
    with both lane lines), at a fifth of the 38 frames' cost; None without the video."""
    if not TEST_VIDEO.is_file():
        return None
    return media.copy_packets(TEST_VIDEO, tmp_path_factory.mktemp("clip") / "clip.mp4", max_frames=8)


@pytest.fixture()
def layout(tmp_path, monkeypatch, short_clip):
    """A data folder holding the 8-frame clip (its road plane is estimated from all; runs search its first frame only)
    and an image, and an empty work folder, the current one."""
    data, work = tmp_path / "data", tmp_path / "work"
    data.mkdir()
    work.mkdir()
    if short_clip is not None:
        shutil.copy(short_clip, data / "clip.mp4")
    Image.fromarray(np.random.default_rng(0).integers(0, 256, (72, 128, 3), dtype=np.uint8)).save(data / "a.png")
    monkeypatch.chdir(work)
    return data, work


@needs_video
def test_default_outputs_go_to_the_current_folder_not_the_data_folder(layout, capsys):
    data, work = layout
    code, err = run(capsys, "detect", data / "clip.mp4", "--frames", "0-0", "--no-progress", "--report", "--lanes", "--save-camera")
    assert code == 0, err
    assert listing(data) == ["a.png", "clip.mp4"]  # nothing written into the data folder
    assert listing(work) == ["clip_boxes.csv", "clip_camera.json", "clip_detected.mp4", "clip_report.html"]


@needs_video
def test_out_names_every_other_output_after_it_in_its_folder(layout, capsys):
    data, work = layout
    code, err = run(capsys, "detect", data / "clip.mp4", "--frames", "0-0", "--no-progress", "--out", "X/run.mp4", "--format", "csv,lanes",
                    "--report", "--save-camera")
    assert code == 0, err
    assert listing(work) == ["X/run.mp4", "X/run_boxes.csv", "X/run_camera.json", "X/run_lanes.csv", "X/run_report.html"]
    assert listing(data) == ["a.png", "clip.mp4"]
    # An --out named as the default (NAME_detected) names the others NAME_*.
    code, err = run(capsys, "detect", data / "a.png", "--out", "Y/a_detected.png")
    assert code == 0, err
    assert listing(work / "Y") == ["a_boxes.csv", "a_detected.png"]


@needs_video
def test_explicit_output_flags_win_and_the_camera_file_joins_the_others(layout, capsys):
    data, work = layout
    code, err = run(capsys, "detect", data / "clip.mp4", "--frames", "0-0", "--no-progress", "--out-dir", "D", "--boxes", "B/b.csv",
                    "--save-camera", "C/c.json")
    assert code == 0, err
    assert listing(work) == ["B/b.csv", "C/c.json", "D/clip_detected.mp4"]
    code, err = run(capsys, "detect", data / "clip.mp4", "--frames", "0-0", "--no-progress", "--no-video", "--out-dir", "E", "--save-camera")
    assert code == 0, err
    assert listing(work / "E") == ["clip_boxes.csv", "clip_camera.json"]


def test_a_batch_writes_into_the_current_folder_too(layout, capsys):
    data, work = layout
    shutil.copy(data / "a.png", data / "b.png")
    code, err = run(capsys, "detect", data / "a.png", data / "b.png")
    assert code == 0, err
    assert listing(work) == ["a_boxes.csv", "a_detected.png", "b_boxes.csv", "b_detected.png"]
    assert listing(data) == ["a.png", "b.png", "clip.mp4"] if (data / "clip.mp4").exists() else ["a.png", "b.png"]


def test_refusals_name_the_flag_not_the_python_keyword(layout, capsys):
    data, work = layout
    (work / "a_detected.png").write_text("earlier")
    code, err = run(capsys, "detect", data / "a.png")
    assert (code, err) == (5, [f"{ERROR}a_detected.png: output exists; pass --overwrite to replace it"])
    shutil.copy(data / "a.png", data / "b.png")  # a batch: each input's error line
    code, err = run(capsys, "detect", data / "a.png", data / "b.png")
    assert code == 7 and err == [f"{ERROR}{data / 'a.png'}: a_detected.png: output exists; pass --overwrite to replace it"]
    code, err = run(capsys, "detect", data / "a.png", "--chunk-frames", "5", "--no-video")
    assert (code, err) == (2, [f"{ERROR}--chunk-frames splits videos into tasks of a dask cluster; give --scheduler too"])
    assert (work / "a_detected.png").read_text() == "earlier"


def test_the_python_api_keeps_its_keywords(tmp_path):
    from vehicle_detection.errors import cli_message

    (tmp_path / "o.csv").write_text("x")
    with pytest.raises(OutputError) as info:
        check_output_path(tmp_path / "o.csv")
    assert str(info.value) == f"{tmp_path / 'o.csv'}: output exists; pass overwrite=True to replace it"
    assert cli_message(info.value) == f"{tmp_path / 'o.csv'}: output exists; pass --overwrite to replace it"
    with pytest.raises(UsageError, match="^chunk_frames splits videos into tasks of a dask cluster; give a client too$"):
        detect_many([tmp_path / "o.csv"], options=InputOptions(video=False), chunk_frames=5)
