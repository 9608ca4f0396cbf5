"""The window-scoring network: its NumPy reference, OpenCV's DNN run of it, the model file, the
search with it, and (with PyTorch) its training and export."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from vehicle_detection.classifier import VehicleClassifier, load_default_model
from vehicle_detection.convnet import _LAYERS, N_OUT, ConvNet, halve
from vehicle_detection.errors import ModelError
from vehicle_detection.refine import apply_offsets
from vehicle_detection.search import _band, _band_windows, search


def random_net(seed=0, channels=(8, 12, 16, 16), scale=0.15, out_bias=None) -> ConvNet:
    rng = np.random.default_rng(seed)
    outs = [*channels, channels[-1], N_OUT]
    ws, bs, cin = [], [], 3
    for (kh, kw, _, _), c in zip(_LAYERS, outs):
        ws.append(rng.normal(0, scale, (kh, kw, cin, c)).astype(np.float32))
        bs.append(rng.normal(0, 0.05, c).astype(np.float32))
        cin = c
    if out_bias is not None:
        ws[-1] = np.zeros_like(ws[-1])
        bs[-1] = np.asarray(out_bias, np.float32)
    return ConvNet(tuple(ws), tuple(bs))


@pytest.mark.parametrize("shape", [(64, 64), (107, 853), (112, 1280), (75, 99)])
def test_dnn_run_equals_the_numpy_reference(shape):
    rng = np.random.default_rng(1)
    image = rng.integers(0, 256, (*shape, 3), dtype=np.uint8)
    net = random_net()
    ref = net.forward(image)
    assert ref.shape == (shape[0] // 8 - 7, shape[1] // 8 - 7, N_OUT)
    np.testing.assert_allclose(net.scores(image), ref, rtol=1e-4, atol=1e-4)


def test_patch_scores_are_the_forward_pass_of_each_patch():
    rng = np.random.default_rng(2)
    patches = rng.integers(0, 256, (5, 64, 64, 3), dtype=np.uint8)
    net = random_net()
    got = net.score_patches(patches)
    for p, g in zip(patches, got):
        np.testing.assert_allclose(g, net.forward(p)[0, 0], rtol=1e-5, atol=1e-5)


def test_a_window_is_scored_from_its_own_pixels():
    """The window at (8r, 8c) of a band is the one the output's (r, c) scores: a bright square
    moved by one cell moves the response by one output cell."""
    net = random_net(3)
    image = np.full((160, 240, 3), 90, np.uint8)
    image[56:88, 96:136] = 230
    moved = np.full_like(image, 90)
    moved[64:96, 104:144] = 230
    a, b = net.forward(image), net.forward(moved)
    # away from the image border (whose zero padding does not move), by one output cell
    np.testing.assert_allclose(a[2:-3, 2:-3], b[3:-2, 3:-2], rtol=1e-4, atol=1e-4)
    assert np.abs(a[2:-3, 2:-3] - b[2:-3, 2:-3]).max() > 1e-2


def test_bad_weights_are_refused():
    net = random_net()
    with pytest.raises(ValueError, match="layer 0"):
        ConvNet((net.weights[0][:, :, :2], *net.weights[1:]), net.biases)
    bad = list(net.weights)
    bad[2] = np.full_like(bad[2], np.nan)
    with pytest.raises(ValueError, match="finite"):
        ConvNet(tuple(bad), net.biases)


@pytest.fixture(scope="module")
def net_model():
    return load_default_model().replace(convnet=random_net(), box_regressor=None)


def test_model_file_round_trip(net_model, tmp_path):
    path = net_model.save(tmp_path / "m.npz")
    back = VehicleClassifier.load(path)
    assert back.convnet is not None
    for a, b in zip(back.convnet.weights, net_model.convnet.weights):
        np.testing.assert_array_equal(a, b)
    assert "convnet" in repr(back)


def test_model_file_with_an_altered_network_is_refused(net_model, tmp_path):
    path = net_model.save(tmp_path / "m.npz")
    with np.load(path) as npz:
        arrays = dict(npz)
    arrays["net_b5"] = arrays["net_b5"] + 1
    np.savez(tmp_path / "bad.npz", **arrays)
    with pytest.raises(ModelError, match="checksum"):
        VehicleClassifier.load(tmp_path / "bad.npz")
    del arrays["net_b5"]
    np.savez(tmp_path / "short.npz", **arrays)
    with pytest.raises(ModelError, match="arrays"):
        VehicleClassifier.load(tmp_path / "short.npz")


def test_search_scores_every_plan_window_with_the_network(frame720):
    """A network that scores 5 everywhere, with constant edge offsets: every window of the plan
    is hot, and each box is its window moved by those offsets."""
    offsets = np.array([0.1, 0.2, -0.1, -0.05], np.float32)
    model = load_default_model()
    model = model.replace(convnet=random_net(out_bias=[5.0, *offsets]), box_regressor=None)
    plan = dataclasses.replace(model.detector_config.plan, threshold=4.0)
    found = search(frame720, model, plan)
    expected = []
    for s in plan.scales:
        band = _band(frame720, s, model.config, plan.overhang_of(s), plan.y_shift, plan.reach_bottom)
        if band is not None:
            expected.append(_band_windows(band, model.config, 1.0))
    windows = np.concatenate(expected)
    assert len(found) == len(windows)
    np.testing.assert_allclose(found.score, 5.0, atol=1e-4)
    np.testing.assert_array_equal(found.data["box"], apply_offsets(windows, np.tile(offsets, (len(windows), 1)), frame720.shape))
    assert len(search(frame720, model, dataclasses.replace(plan, threshold=5.5))) == 0


@pytest.fixture(scope="module")
def frame720():
    rng = np.random.default_rng(4)
    return rng.integers(0, 256, (720, 1280, 3), dtype=np.uint8)


def test_export_folds_batch_normalisation_exactly():
    torch = pytest.importorskip("torch", reason="training the network needs PyTorch (the train-cnn extra)")
    from vehicle_detection.training.convnet import export, network

    torch.manual_seed(0)
    model = network((8, 12, 16, 16))
    for m in model:
        if isinstance(m, torch.nn.BatchNorm2d):
            m.running_mean.uniform_(-0.5, 0.5)
            m.running_var.uniform_(0.5, 2.0)
            m.weight.data.uniform_(0.5, 1.5)
            m.bias.data.uniform_(-0.2, 0.2)
    model.eval()
    rng = np.random.default_rng(5)
    patches = rng.integers(0, 256, (6, 64, 64, 3), dtype=np.uint8)
    half = np.stack([halve(p) for p in patches]).astype(np.float32)
    x = torch.from_numpy(((half / 255 - 0.5) / 0.25).transpose(0, 3, 1, 2).copy())
    with torch.no_grad():
        want = model(x)[:, :, 0, 0].numpy()
    np.testing.assert_allclose(export(model).score_patches(patches), want, rtol=1e-4, atol=1e-4)


def test_training_learns_a_separable_set():
    pytest.importorskip("torch", reason="training the network needs PyTorch (the train-cnn extra)")
    from vehicle_detection.training.convnet import ConvNetTraining, fit_convnet

    rng = np.random.default_rng(6)
    n = 128  # all right and the offsets within 0.03 after 12 epochs, as with 256 patches
    patches = rng.integers(60, 120, (n, 64, 64, 3), dtype=np.uint8)
    labels = np.arange(n) % 2
    patches[labels == 1, 20:44, 12:52] = 20  # a dark block: the "vehicle"
    offsets = np.full((n, 4), np.nan, np.float32)
    offsets[labels == 1] = [0.1, 0.2, -0.1, -0.2]
    net, record = fit_convnet(patches, labels, offsets, ConvNetTraining(channels=(8, 8, 8, 8), epochs=12, batch=32, learning_rate=5e-3, threads=1))  # one thread: the suite runs a worker a core
    out = net.score_patches(patches)
    assert ((out[:, 0] > 0) == (labels == 1)).mean() > 0.95
    np.testing.assert_allclose(out[labels == 1, 1:].mean(axis=0), [0.1, 0.2, -0.1, -0.2], atol=0.08)
    assert record["n_box_targets"] == n // 2


def test_train_cli_builds_a_network_model_that_detect_runs(tmp_path, capsys):
    pytest.importorskip("torch", reason="training the network needs PyTorch (the train-cnn extra)")
    from pathlib import Path

    from conftest import small_archives

    from vehicle_detection.cli.main import main

    import json

    data = small_archives(tmp_path / "data", 60)
    # The first of the six labelled stills (two cars: the edge targets; its road and trees: the
    # hard negatives): each round's windows and hard negatives come from it, at a sixth of the time.
    repo = Path(__file__).resolve().parents[1]
    doc = json.loads((repo / "dev_set" / "test_images.json").read_text())
    doc["video"] = str(repo / "test_images")
    doc["frames"] = {k: doc["frames"][k] for k in ("0",)}
    labels = tmp_path / "one_still.json"
    labels.write_text(json.dumps(doc))
    model = tmp_path / "net.npz"
    args = ["train", "--data-dir", str(data), "--labels", str(labels), "--classifier", "convnet", "--epochs", "1",
            "--rounds", "2", "--model", str(model), "--json"]
    assert main(args) == 0
    loaded = VehicleClassifier.load(model)
    assert loaded.convnet is not None and loaded.box_regressor is None
    record = loaded.metrics["convnet"]
    assert record["rounds"] == 2 and record["n_box_targets"] > 0 and record["hard_negatives"] > 0
    assert loaded.detector_config.plan.threshold == 2.0
    scales = [s.scale for s in loaded.detector_config.plan.scales]
    assert min(scales) == 0.75 and max(scales) == 6.0
    capsys.readouterr()
    assert main(["detect", str(Path(__file__).resolve().parents[1] / "test_images" / "test1.jpg"), "--model", str(model),
                 "--out", str(tmp_path / "o.jpg"), "--boxes", str(tmp_path / "b.csv")]) == 0
    assert (tmp_path / "b.csv").read_text().startswith("frame,")
    # without labelled frames there is nothing to learn the cars' edges from: one line, exit 3
    assert main(["train", "--data-dir", str(data), "--classifier", "convnet", "--model", str(tmp_path / "x.npz")]) == 3
    assert "--labels" in capsys.readouterr().err


@pytest.mark.parametrize("shape", [(480, 640), (533, 1280), (375, 1242), (352, 640), (540, 960)])
@pytest.mark.parametrize("horizon", [None, 0.27, 0.45])
def test_the_network_plan_covers_the_road_area_of_any_frame_shape(shape, horizon):
    """4:3, 2.4:1, the wide stills of a driving benchmark, 640x352 and 960x540: windows over
    every column and every row below the horizon, from a side of at most 36 pixels (cars about 30
    pixels tall) to at least half the frame height."""
    from vehicle_detection.search import plan_windows
    from vehicle_detection.training.convnet import detector_settings

    base = load_default_model()
    dc = detector_settings(base.detector_config)
    plan = dataclasses.replace(dc.plan, horizon=horizon)
    h, w = shape
    wins = np.concatenate([x for x in plan_windows(shape, plan, base.config) if len(x)])
    sides = wins[:, 3] - wins[:, 1]
    assert sides.min() <= 36 and sides.max() >= h / 2
    cols = np.zeros(w, bool)
    rows = np.zeros(h, bool)
    for x1, y1, x2, y2 in wins:
        cols[x1:x2] = True
        rows[y1:y2] = True
    assert cols.all()
    top = round((plan.reference_horizon if horizon is None else horizon) * h)
    assert rows[top:].all(), f"rows {np.flatnonzero(~rows[top:])[:5] + top} below the horizon are never searched"


def test_augmented_edge_offsets_follow_the_picture():
    """The zoom, shift and mirror of training move a patch's car and its edge offsets alike: a
    dark box drawn where the offsets say lies where the augmented picture has it."""
    torch = pytest.importorskip("torch", reason="training the network needs PyTorch (the train-cnn extra)")
    from vehicle_detection.training.convnet import _augment

    rng = np.random.default_rng(7)
    torch.manual_seed(7)  # the noise is torch's: its state otherwise depends on the tests run before in this process
    b = 64
    x = torch.full((b, 3, 32, 32), 200.0)
    box = (8, 10, 24, 26)  # x1, y1, x2, y2 in pixels of the 32x32 window
    x[:, :, box[1] : box[3], box[0] : box[2]] = 10.0
    t = torch.tensor([[box[0] / 32, box[1] / 32, box[2] / 32 - 1, box[3] / 32 - 1]] * b)
    # the light changes too, but the box stays the darkest part of each patch
    out, t2 = _augment(torch, x.clone(), t.clone(), rng, blur=0.0)
    for img, off in zip(out, t2.numpy()):
        dark = (img.mean(dim=0) < img.mean()).numpy()
        ys, xs = np.nonzero(dark)
        got = np.array([xs.min(), ys.min(), xs.max() + 1, ys.max() + 1]) / 32
        want = np.array([off[0], off[1], off[2] + 1, off[3] + 1])
        np.testing.assert_allclose(got, want, atol=1.6 / 32)


def test_a_car_60_pixels_tall_in_a_wide_still_is_found_with_a_fitting_box():
    """A 1242x375 still (the wide stills of a public driving benchmark): test1 scaled so that its
    black car is 60 pixels tall, cut to 375 rows with the horizon where the plan has it, and
    widened to 1242 columns with mirrored edges. The shipped network model boxes the car."""
    import cv2

    from vehicle_detection import Detector
    from vehicle_detection.classifier import load_model
    from vehicle_detection.geometry import box_iou
    from vehicle_detection.io.images import read_image

    root = __import__("pathlib").Path(__file__).resolve().parents[1]
    image = read_image(root / "test_images" / "test1.jpg")
    car = np.array([817, 411, 942, 493], np.float64)  # dev_set/test_images.json
    f = 60 / (car[3] - car[1])
    small = cv2.resize(image, (round(1280 * f), round(720 * f)), interpolation=cv2.INTER_AREA)
    top = round(0.583 * small.shape[0] - 0.583 * 375)
    pad = (1242 - small.shape[1]) // 2
    still = cv2.copyMakeBorder(small[top : top + 375], 0, 0, pad, 1242 - small.shape[1] - pad, cv2.BORDER_REFLECT_101)
    assert still.shape == (375, 1242, 3)
    want = car * f + [pad, -top, pad, -top]
    assert 59 <= want[3] - want[1] <= 61
    found = Detector(load_model("convnet")).detect_image(still)
    assert len(found), "no vehicle found"
    iou = box_iou(found.xyxy, want[None])[:, 0]
    assert iou.max() >= 0.7, f"best box {found.xyxy[iou.argmax()].tolist()} against {want.round().tolist()}: IoU {iou.max():.2f}"


def test_refine_refuses_a_network_model(tmp_path, capsys):
    from pathlib import Path

    from vehicle_detection.cli.main import main

    labels = Path(__file__).resolve().parents[1] / "dev_set" / "test_images.json"
    assert main(["refine", "--labels", str(labels), "--model", "convnet", "--out", str(tmp_path / "r.npz")]) == 3
    err = capsys.readouterr().err
    assert "network model" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "r.npz").exists()


def _one_car_frame(tmp_path, car):
    """A labelled folder of one grey 720x1280 frame with a red car box, and its annotations."""
    import json

    from vehicle_detection.io.images import write_image
    from vehicle_detection.metrics.detection import load_annotations

    frame = np.full((720, 1280, 3), 120, np.uint8)
    x1, y1, x2, y2 = car
    frame[y1:y2, x1:x2] = (200, 20, 20)
    (tmp_path / "frames").mkdir()
    write_image(tmp_path / "frames" / "a.png", frame)
    spec = {"video": "frames", "frames": {"0": {"file": "a.png", "cars": [list(car)], "ignore": []}}}
    (tmp_path / "labels.json").write_text(json.dumps(spec))
    return load_annotations(tmp_path / "labels.json")


def test_a_side_on_car_trains_wide_windows_squeezed_to_the_patch(tmp_path):
    """A car twice as wide as tall: square windows around it (side at least 0.8 times its
    width) show it over at most 5/8 of their rows; the wide windows, squeezed to 64x64, show it
    over more than 2/3 of their rows, as the search's wide windows will. With ``wide=1`` there
    are none."""
    from vehicle_detection.training.convnet import ConvNetTraining, frame_samples

    ann = _one_car_frame(tmp_path, (500, 450, 700, 550))

    def red_rows(samples):
        cars = samples.patches[samples.labels == 1].astype(int)
        red = (cars[..., 0] > 150) & (cars[..., 1] < 80)
        return (red.mean(axis=2) > 0.3).mean(axis=1)  # fraction of each patch's rows the car crosses

    square = red_rows(frame_samples([ann], ConvNetTraining(wide=1.0)))
    both = red_rows(frame_samples([ann], ConvNetTraining(wide=2.0)))
    assert len(square) and square.max() <= 0.66
    assert len(both) > len(square) + 5 and (both > 0.68).sum() >= len(both) - len(square) - 2


def test_the_network_plan_has_wide_windows_beside_the_square_ones():
    """Wide windows (``wide=2``: twice as wide as tall) search the same bands as the base plan's
    square windows up to scale 4; by default (``wide=1``) there are none."""
    from vehicle_detection.training.convnet import detector_settings

    base = load_default_model().detector_config
    plan = detector_settings(base, wide=2.0).plan
    square = [(s.scale, s.y_start, s.y_stop) for s in base.plan.scales if s.scale <= 4]
    assert [(s.scale, s.y_start, s.y_stop) for s in plan.scales if s.aspect == 2.0] == square
    assert all(s.aspect == 1.0 for s in detector_settings(base).plan.scales)


def test_the_network_model_turns_heat_into_boxes_as_the_box_refinement_does():
    """The network's windows carry their own boxes, as the box refinement's do: the same
    clustering and voting (the leave-one-camera-out folds and the shipped model alike; once the
    shipped model had the plain heat boxes of an unrefined model, and its boxes fitted loosely)."""
    from vehicle_detection.classifier import load_model
    from vehicle_detection.config import DetectorConfig
    from vehicle_detection.training.convnet import detector_settings
    from vehicle_detection.training.fit import BOX_VOTE, CLUSTER_IOU

    tracker = detector_settings(DetectorConfig()).tracker
    assert (tracker.cluster_iou, tracker.box_vote, tracker.window_inset) == (CLUSTER_IOU, BOX_VOTE, (0.0, 0.0, 0.0, 0.0))
    assert load_model("convnet").detector_config.tracker == tracker
    assert load_model("svm").detector_config.tracker == tracker  # the refined SVM's, for the same reason
