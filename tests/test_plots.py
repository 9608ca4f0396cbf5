"""Tests for vehicle_detection.viz.plots: every figure helper on small synthetic inputs (Agg backend)."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")

import numpy as np  # noqa: E402
import pytest  # noqa: E402
from matplotlib import pyplot as plt  # noqa: E402
from PIL import Image  # noqa: E402

from vehicle_detection.viz import plots  # noqa: E402
from vehicle_detection.config import DetectorConfig  # noqa: E402
from vehicle_detection.detections import Detections  # noqa: E402
from vehicle_detection.detector import Detector  # noqa: E402
from vehicle_detection.metrics.detection import Annotations, FrameLabels  # noqa: E402
from vehicle_detection.features import COLOR_SPACES, FeatureConfig  # noqa: E402
from vehicle_detection.search import SearchPlan, SearchScale  # noqa: E402
from vehicle_detection.tracker import TrackerConfig  # noqa: E402

RNG = np.random.default_rng(0)
CFG = FeatureConfig()


@pytest.fixture(autouse=True)
def _close_figures():
    yield
    plt.close("all")


def patch():
    return RNG.integers(0, 256, (64, 64, 3), dtype=np.uint8)


def frame(h=180, w=320):
    return RNG.integers(0, 256, (h, w, 3), dtype=np.uint8)


PLAN = SearchPlan(scales=(SearchScale(1.0, 40, 120), SearchScale(2.0, 40, 180, step=2)), reference_height=180)


def small_detector():
    """A real detector with a small plan and low thresholds (its windows come from windows())."""
    return Detector(config=DetectorConfig(plan=PLAN, tracker=TrackerConfig(threshold=1.0, cell=8), image_threshold=1.0))


def windows(n=3):
    boxes = np.array([[10 + 20 * i, 50, 74 + 20 * i, 114] for i in range(n)], np.int64)
    return Detections(boxes, score=np.linspace(0.5, 2.0, n), data={"scale_index": np.arange(n) % 2})


def heat(h=180, w=320, cell=8):
    out = np.zeros((h // cell, w // cell), np.float32)
    out[6:14, 2:12] = 3.0
    return out


def png_ok(path):
    with Image.open(path) as img:
        img.verify()
    return path.stat().st_size


# --- paths and files ----------------------------------------------------------------------------


def test_notebook_paths_default(tmp_path, monkeypatch):
    nb = tmp_path / "repo" / "notebooks"
    nb.mkdir(parents=True)
    monkeypatch.delenv("VEHICLE_DETECTION_DATA", raising=False)
    monkeypatch.delenv(plots.OUTPUT_ENV, raising=False)
    p = plots.notebook_paths(nb)
    assert p.repo == (tmp_path / "repo").resolve()
    assert p.data == (tmp_path / "repo" / "data").resolve()
    assert p.output == (tmp_path / "repo" / "output_images").resolve()
    assert p.output.is_dir()


def test_notebook_paths_shared_data_beside_the_checkout(tmp_path, monkeypatch):
    nb = tmp_path / "repo" / "notebooks"
    nb.mkdir(parents=True)
    (tmp_path / "shared" / "data").mkdir(parents=True)
    monkeypatch.delenv("VEHICLE_DETECTION_DATA", raising=False)
    monkeypatch.delenv(plots.OUTPUT_ENV, raising=False)
    p = plots.notebook_paths(nb)
    assert p.data == (tmp_path / "shared" / "data").resolve()
    assert str(p) == "repository repo/, data ../shared/data, output output_images"


def test_notebook_paths_from_environment(tmp_path, monkeypatch):
    monkeypatch.setenv("VEHICLE_DETECTION_DATA", str(tmp_path / "d"))
    monkeypatch.setenv(plots.OUTPUT_ENV, str(tmp_path / "o"))
    p = plots.notebook_paths(tmp_path)
    assert p.data == (tmp_path / "d").resolve()
    assert p.output == (tmp_path / "o").resolve() and p.output.is_dir()


def test_save_figure_small_plot_is_truecolour(tmp_path):
    fig, ax = plt.subplots(figsize=(3, 2))
    ax.plot([0, 1], [0, 1])
    path = plots.save_figure(fig, tmp_path / "sub" / "line.png")
    assert png_ok(path) < 50_000
    assert Image.open(path).mode in ("RGB", "RGBA")


def test_save_figure_photo_is_quantised_keeping_accent_colours(tmp_path):
    # random pixels: far above the budget at any size (a quarter of the 800x600 it was drawn at)
    fig, ax = plt.subplots(figsize=(4, 3))
    ax.imshow(RNG.integers(0, 256, (150, 200, 3), dtype=np.uint8))
    ax.plot([0, 199], [75, 75], color=plots.BOX_COLOR, lw=6)
    path = plots.save_figure(fig, tmp_path / "photo.png", budget=10_000)
    png_ok(path)
    img = Image.open(path)
    assert img.mode == "P"
    colours = {c for _, c in img.convert("RGB").getcolors(maxcolors=1 << 16)}
    assert (0, 255, 0) in colours  # the box colour survives exactly


def test_save_figure_show_displays_the_file_and_closes_the_figure(tmp_path, capsys):
    fig, ax = plt.subplots(figsize=(3, 2))
    ax.plot([0, 1], [0, 1])
    plots.save_figure(fig, tmp_path / "line.png")  # not in a kernel: nothing shown, figure kept
    assert plt.fignum_exists(fig.number) and capsys.readouterr().out == ""
    plots.save_figure(fig, tmp_path / "line.png", show=True)
    assert not plt.fignum_exists(fig.number)
    assert "Image" in capsys.readouterr().out  # IPython's display() outside a kernel prints the repr


def test_markdown_table():
    text = plots.markdown_table(
        [{"a": "x", "b": 0.12345, "c": [0, 1]}, {"a": "y", "b": 1.0, "c": (2,)}],
        [("a", "name", ""), ("b", "value", ".2f"), ("c", "channels", "")],
    )
    assert text.splitlines() == ["| name | value | channels |", "| --- | --- | --- |", "| x | 0.12 | 0,1 |", "| y | 1.00 | 2 |"]


# --- figures ------------------------------------------------------------------------------------


def test_image_grid_with_blanks_and_labels(tmp_path):
    fig = plots.image_grid([patch(), None, patch(), patch()], ncols=2, titles=["a", "", "c", "d"], row_labels=["r0", "r1"], suptitle="t")
    assert len(fig.axes) == 4
    assert not fig.axes[1].axison
    png_ok(plots.save_figure(fig, tmp_path / "grid.png"))


def test_counts_figure():
    fig = plots.counts_figure({"non-vehicles/GTI": 10, "vehicles/KITTI": 20}, duplicates={"non-vehicles/GTI": 2})
    assert len(fig.axes) == 1


def test_feature_figures(tmp_path):
    patches = {"vehicle": patch(), "non-vehicle": patch()}
    figs = [
        plots.color_space_figure(patches),  # every colour space
        plots.hog_figure(patches, CFG),
        plots.hog_parameters_figure(patches["vehicle"], [FeatureConfig(signed=False, orientations=9), CFG]),
        plots.spatial_bins_figure(patches, CFG),
        plots.histogram_figure(patches, CFG),
    ]
    assert len(figs[0].axes) == len(COLOR_SPACES) * 7
    assert len(figs[1].axes) == 4 * 4
    raw = RNG.normal(size=CFG.n_features)
    figs.append(plots.feature_vector_figure(raw, raw, CFG.layout(), title="t"))
    assert len(figs[-1].axes) == 6
    for i, fig in enumerate(figs):
        assert png_ok(plots.save_figure(fig, tmp_path / f"f{i}.png")) < 300_000


def test_classifier_figures():
    split = {"accuracy": 0.99, "precision": 0.98, "recall": 0.97, "n_test": 100}
    plots.accuracy_figure({"random_split": split, "grouped_split": split})
    row = dict(color_space="YCrCb", hog_channels=[0, 1, 2], orientations=9, signed=False, hog_sqrt=False, pixels_per_cell=8,
               spatial_size=0, hist_bins=0, n_features=100, random_accuracy=0.99, grouped_accuracy=0.98)
    assert plots.sweep_label(row) == "YCrCb ch012 o9 ppc8 HOG only"
    assert plots.sweep_label({**row, "signed": True, "hog_sqrt": True, "spatial_size": 16, "hist_bins": 32}) == "YCrCb ch012 o9s ppc8 sqrt sp16/h32"
    fig = plots.sweep_figure([row, {**row, "orientations": 11, "grouped_accuracy": 0.97}], n_images=3000)
    assert len(fig.axes) == 2
    fig = plots.confusion_figure({"tn": 90, "fp": 10, "fn": 5, "tp": 95}, title="t")
    texts = [t.get_text() for t in fig.axes[0].texts]
    assert "90\n90.0%" in texts and "5\n5.0%" in texts


def test_search_plan_table():
    lines = plots.search_plan_table((180, 320, 3), PLAN, CFG).splitlines()
    assert lines[0] == "| scale | window (px) | rows searched | step (px) | overlap | windows |"
    assert lines[2].startswith("| 1 | 64 | 40-120 | 16 | 75.0% | ")
    assert lines[3].startswith("| 2 | 128 | 40-180 | 32 | 75.0% | ")
    n = [int(line.rsplit("|", 2)[1].replace(",", "")) for line in lines[2:]]
    assert lines[-1].startswith("| all |") and n[-1] == sum(n[:-1]) > 0


def test_window_grid_figure():
    fig = plots.window_grid_figure(frame(), PLAN, CFG, rows=(20, 180))
    assert len(fig.axes) == 2
    assert fig.axes[0].get_ylim() == (180, 20)
    assert "scale 2" in fig.axes[1].get_title()


def test_detection_stages_and_boxes_grid(tmp_path):
    det = small_detector()
    f = frame()
    result = Detections([[16, 48, 96, 112]], score=[3.0])
    fig = plots.detection_stages_figure([("a", f, windows(), result), ("b", f, windows(0), Detections.empty())], det, rows=(40, 180))
    assert len(fig.axes) == 8
    # a frame without hot windows: the search returns Detections without a scale_index column
    plots.detection_stages_figure([("c", f, Detections.empty(), Detections.empty())], det)
    assert fig.axes[0].texts[-1].get_text() == "3 windows"
    png_ok(plots.save_figure(fig, tmp_path / "stages.png"))
    fig = plots.boxes_grid_figure([("a", f, result.xyxy), ("b", f, np.zeros((0, 4)))], ncols=3)
    assert [ax.get_title() for ax in fig.axes[:2]] == ["a: 1 vehicle", "b: 0 vehicles"]


def test_video_figures(tmp_path):
    det = small_detector()
    records = [
        (frame(), i, windows(), Detections([[16, 48, 96, 112]], score=[5.0], track_id=[0], frame=i), heat() * (i + 1))
        for i in range(2)
    ]
    fig = plots.frame_sequence_figure(records, det, rows=(40, 180))
    assert len(fig.axes) == 6
    table = Detections([[1, 2, 30, 40], [1, 2, 30, 40], [50, 2, 90, 40]], track_id=[0, 0, 3], frame=[0, 1, 1])
    fig = plots.tracks_timeline_figure(table, 4)
    assert [t.get_text() for t in fig.axes[0].get_yticklabels()] == ["car 0", "car 3"]
    plots.tracks_timeline_figure(Detections.empty(tracked=True), 4)
    ann = Annotations(None, {0: FrameLabels(cars=[[16, 48, 96, 112], [200, 50, 260, 100]], ignore=[[0, 0, 10, 10]]), 5: FrameLabels(cars=[])})
    fig = plots.labelled_frames_figure({0: frame(), 5: frame()}, ann, Detections([[16, 48, 96, 112], [120, 60, 150, 90]]))
    assert fig.axes[0].get_title() == "frame 0: TP 1, FP 1, FN 1"
    assert fig.axes[1].get_title() == "frame 5: TP 0, FP 0, FN 0"
    png_ok(plots.save_figure(fig, tmp_path / "labelled.png"))


def test_track_frames_keeps_the_requested_window():
    class Det(Detector):
        def windows(self, f):
            return Detections([[8, 8, 72, 72]], score=[1.0])

    frames = (frame() for _ in range(10))
    records = plots.track_frames(Det(config=small_detector().config), frames, first=3, count=2)
    assert [r[1] for r in records] == [3, 4]
    assert all(len(r[2]) == 1 for r in records)
    assert records[0][4] is not records[1][4] and records[1][4].max() > records[0][4].max()


def test_showcase_configs_end_with_the_model_config():
    configs = plots.showcase_configs(CFG)
    assert configs[-1] is CFG
    assert len({c for c in configs}) == len(configs)
    assert {c.color_space for c in configs} >= {"RGB", "HLS", "YCrCb"}
