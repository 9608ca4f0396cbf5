"""Training the window-scoring network (:class:`~vehicle_detection.convnet.ConvNet`).

Needs PyTorch (the ``train-cnn`` extra): detection does not, it runs the trained arrays in NumPy.

The training set is the archives' 64x64 patches plus, from every labelled frame of the training
cameras, windows cut as the search cuts them (the frame resized to the plan's reference height):

* **cars**: square windows jittered around each labelled car (side 0.8 to 1.4 times its larger
  dimension, centre moved by up to 0.15 sides), kept where their IoU with the car is at least
  0.45, each with the edge offsets that move it onto the car (the box head's targets); with
  ``wide`` > 1, a car at least ``wide_from`` times as wide as tall (seen side-on or at an angle)
  also gets windows ``wide`` times as wide as tall, jittered alike: the search's wide windows,
  squeezed to 64x64 (measured, not shipped: docs/experiments.md, "Wide windows");
* **background**: windows of the search's sizes and shapes anywhere below the top fifth of the
  frame that overlap no car (IoU < 0.2) and lie mostly outside every ``ignore`` box;
* **hard background**, in later rounds: the windows of the training frames the previous round's
  network scores highest among those.

Every batch is augmented on the fly for other cameras and light: mirror, brightness, contrast,
gamma, white balance (a gain per channel), saturation, grey, noise.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np

from ..convnet import MEAN, N_OUT, STD, ConvNet, halve
from ..errors import require
from ..geometry import box_iou
from ..metrics.detection import Annotations
from ..refine import crop_windows, edge_offsets, jittered_windows, working_frame
from .fit import boxed_windows_tracker
from .mining import _fraction_inside, labelled_frames

__all__ = ["ConvNetTraining", "FrameSamples", "detector_settings", "export", "fit_convnet", "frame_samples", "hard_windows", "network", "samples_from", "with_convnet"]


@dataclass(frozen=True)
class ConvNetTraining:
    """How the network is trained.

    Parameters
    ----------
    channels : tuple of int
        Output channels of the first four layers (the fifth has the fourth's).
    epochs : int
    batch : int
    learning_rate : float
    box_weight : float
        Weight of the edge offsets' loss beside the score's.
    per_car : int
        Jittered windows drawn around each labelled car (fewer are kept: IoU >= 0.45).
    negatives_per_frame : int
        Background windows drawn in each labelled frame.
    wide : float
        Width over height of the wide windows (1: none, the shipped model's setting).
    wide_from : float
        Cars at least this wide for their height train the wide windows too.
    seed : int
    threads : int
        PyTorch's threads.
    """

    channels: tuple[int, int, int, int] = (16, 32, 32, 32)
    epochs: int = 8
    batch: int = 256
    learning_rate: float = 3e-3
    box_weight: float = 4.0
    per_car: int = 24
    negatives_per_frame: int = 100
    wide: float = 1.0
    wide_from: float = 1.3
    seed: int = 0
    threads: int = 2


@dataclass
class FrameSamples:
    """Windows cut from labelled frames: patches, labels and the cars' edge offsets."""

    patches: np.ndarray  # uint8 (N, 64, 64, 3)
    labels: np.ndarray  # int8 (N,)
    offsets: np.ndarray  # float32 (N, 4); NaN where there is no box target
    sources: np.ndarray  # str (N,): the labels file's camera, for the record

    @classmethod
    def empty(cls) -> FrameSamples:
        return cls(np.zeros((0, 64, 64, 3), np.uint8), np.zeros(0, np.int8), np.zeros((0, 4), np.float32), np.zeros(0, str))

    def __len__(self) -> int:
        return len(self.labels)

    def concatenate(self, *others: FrameSamples) -> FrameSamples:
        parts = (self, *others)
        return FrameSamples(*(np.concatenate([getattr(p, f.name) for p in parts]) for f in dataclasses.fields(self)))


def _background(cars: np.ndarray, ignore: np.ndarray, windows: np.ndarray) -> np.ndarray:
    """Which windows are background: no car overlaps them (IoU < 0.2), and at most half of
    each lies inside an ignore box."""
    keep = np.ones(len(windows), bool)
    if len(cars):
        keep &= box_iou(windows, cars).max(axis=1) < 0.2
    if len(ignore) and len(windows):
        keep &= _fraction_inside(windows, ignore).max(axis=1) <= 0.5
    return keep


def _jittered(car: np.ndarray, rng: np.random.Generator, n: int, aspect: float) -> np.ndarray:
    """``n`` windows ``aspect`` times as wide as tall jittered around ``car``: square ones
    (:func:`~vehicle_detection.refine.jittered_windows`) in the frame squeezed ``aspect`` times
    across, stretched back. (Squeezing leaves IoU unchanged.)"""
    squeeze = np.array([aspect, 1.0, aspect, 1.0])
    return jittered_windows(car / squeeze, rng, n, size_range=(0.8, 1.4), shift=0.15) * squeeze


def frame_samples(annotations: Sequence[Annotations], config: ConvNetTraining, *, reference_height: int = 720) -> FrameSamples:
    """Car and background windows of every labelled frame (see the module docstring)."""
    rng = np.random.default_rng(config.seed)
    parts: list[FrameSamples] = []
    for ann in annotations:
        name = ann.camera or (ann.path.stem if ann.path else "labels")
        for _, frame, labels in labelled_frames(ann):
            work, f = working_frame(frame, reference_height)
            h, w = work.shape[:2]
            cars = np.asarray(labels.cars, np.float64).reshape(-1, 4) * f
            ignore = np.asarray(labels.ignore, np.float64).reshape(-1, 4) * f
            wins, offs = [], []
            for car in cars:
                shapes = [1.0]
                if config.wide > 1 and (car[2] - car[0]) >= config.wide_from * (car[3] - car[1]):
                    shapes.append(config.wide)
                for aspect in shapes:
                    jit = _jittered(car, rng, config.per_car, aspect)
                    good = box_iou(jit, car[None])[:, 0] >= 0.45
                    wins.append(jit[good])
                    offs.append(edge_offsets(jit[good], np.repeat(car[None], good.sum(), 0)))
            n_pos = sum(len(x) for x in wins)
            side = np.exp(rng.uniform(np.log(40), np.log(min(330, h * 0.9)), config.negatives_per_frame * 2))
            width = side * np.where(rng.random(len(side)) < 1 / 3, config.wide, 1.0) if config.wide > 1 else side
            x0 = rng.uniform(-0.3, 1.0, len(side)) * w - width * 0.35
            y0 = rng.uniform(0.2 * h, h - side * 0.6)
            neg = np.stack([x0, y0, x0 + width, y0 + side], axis=1)
            neg = neg[_background(cars, ignore, neg)][: config.negatives_per_frame]
            windows = np.concatenate([*wins, neg]) if n_pos else neg
            patches = crop_windows(work, windows, 64)
            labels_ = np.r_[np.ones(n_pos, np.int8), np.zeros(len(neg), np.int8)]
            offsets = np.full((len(windows), 4), np.nan, np.float32)
            if n_pos:
                offsets[:n_pos] = np.concatenate(offs)
            parts.append(FrameSamples(patches, labels_, offsets, np.full(len(windows), name)))
    return FrameSamples.empty().concatenate(*parts)


def hard_windows(net: ConvNet, annotations: Sequence[Annotations], plan, *, per_frame: int = 40, threshold: float = -1.0,
                 reference_height: int = 720) -> FrameSamples:
    """The background windows of labelled frames that ``net`` scores highest (above
    ``threshold``, at most ``per_frame`` a frame, no two overlapping by more than IoU 0.5),
    searched at the plan's scales over the whole frame height."""
    from ..features import FeatureConfig
    from ..search import SearchScale, plan_bands

    cfg = FeatureConfig()
    # every scale over the whole frame height: the training cameras' horizons differ
    scales = tuple(SearchScale(s.scale, 0, reference_height, step=s.step, aspect=s.aspect) for s in plan.scales)
    plan = dataclasses.replace(plan, scales=scales, horizon=None, reach_bottom=False)
    parts: list[FrameSamples] = []
    for ann in annotations:
        name = ann.camera or (ann.path.stem if ann.path else "labels")
        for _, frame, labels in labelled_frames(ann):
            work, f = working_frame(frame, reference_height)
            cars = np.asarray(labels.cars, np.float64).reshape(-1, 4) * f
            ignore = np.asarray(labels.ignore, np.float64).reshape(-1, 4) * f
            wins, scores = [], []
            for _, image, rows, cols, windows in plan_bands(work, plan, cfg):
                margins = net.forward(image)[np.ix_(rows, cols)][..., 0].ravel()
                keep = margins > threshold
                if keep.any():
                    wins.append(windows[keep])
                    scores.append(margins[keep])
            if not wins:
                continue
            wins, scores = np.concatenate(wins), np.concatenate(scores)
            bg = _background(cars, ignore, wins)
            wins, scores = wins[bg], scores[bg]
            order = np.argsort(-scores)
            chosen: list[int] = []
            for i in order:  # spread over the frame: no two chosen windows overlapping much
                if len(chosen) >= per_frame:
                    break
                if not chosen or box_iou(wins[i : i + 1], wins[chosen]).max() < 0.5:
                    chosen.append(int(i))
            if chosen:
                w = wins[chosen]
                parts.append(FrameSamples(crop_windows(work, w, 64), np.zeros(len(w), np.int8),
                                                   np.full((len(w), 4), np.nan, np.float32), np.full(len(w), name)))
    return FrameSamples.empty().concatenate(*parts)


#: The network model's window threshold (a logit: 2 is a probability of 0.88).
THRESHOLD = 2.0
#: The candidate horizons the cars are searched at where the road's lines give none: up to a
#: fifth of the picture height (a phone high on the windscreen, a camera tilted down).
CANDIDATES = (0.19, 0.27, 0.35, 0.43, 0.51, 0.59, 0.67)


def detector_settings(base, *, threshold: float = THRESHOLD, candidates=CANDIDATES, small: bool = True, large: bool = True,
                      wide: float = 1.0):
    """The detector settings of a network model, from the SVM model's (``base``, a
    :class:`~vehicle_detection.config.DetectorConfig`).

    The plan gains two scales the network scores cheaply: 48-pixel windows near the horizon
    (``small``: cars about 30 pixels tall in a 540-row frame), 384-pixel windows over the
    lower half (``large``: cars half the frame height), and beside each of the base plan's
    scales up to 4 (windows 64 to 256 pixels tall) windows ``wide`` times as wide as tall, for
    cars seen side-on or at an angle (``wide=1``: none). The SVM's two-stage search does not
    apply (the network scores a band in one pass). Bands that reach the frame's bottom keep
    reaching it when a high horizon moves the bands up (:attr:`SearchPlan.reach_bottom`). The
    windows carry the network's boxes, so the heat becomes boxes as the box refinement's do
    (:func:`~vehicle_detection.training.fit.boxed_windows_tracker`: blobs split by their boxes'
    clusters, boxes voted).
    """
    from ..search import SearchScale

    plan = base.plan
    scales = list(plan.scales)
    if small:
        scales.insert(0, SearchScale(0.75, 396, 468, step=1))
    if wide > 1:
        scales += [dataclasses.replace(s, aspect=float(wide)) for s in plan.scales if s.aspect == 1 and s.scale <= 4]
    if large:
        scales.append(SearchScale(6.0, 336, 720, step=1))
    plan = dataclasses.replace(plan, scales=tuple(scales), threshold=float(threshold), coarse_margin=None, reach_bottom=True)
    cars = dataclasses.replace(base.car_horizon, candidates=tuple(candidates), min_margin=float(threshold) + 1.0)
    return base.replace(plan=plan, car_horizon=cars, tracker=boxed_windows_tracker(base.tracker))


def _halve(patches: np.ndarray) -> np.ndarray:
    return np.stack([halve(p) for p in patches]).astype(np.float32) if len(patches) else np.zeros((0, 32, 32, 3), np.float32)


def fit_convnet(
    patches: np.ndarray,
    labels: np.ndarray,
    offsets: np.ndarray,
    config: ConvNetTraining = ConvNetTraining(),
    *,
    progress: bool = False,
) -> tuple[ConvNet, dict]:
    """Train the network on 64x64 patches.

    Parameters
    ----------
    patches : ndarray of uint8, shape (N, 64, 64, 3)
    labels : ndarray of int, shape (N,)
        1 vehicle, 0 other.
    offsets : ndarray of float, shape (N, 4)
        Edge offsets of each vehicle patch's car (NaN rows: no box target).
    config : ConvNetTraining

    Returns
    -------
    (ConvNet, dict)
        The network and a record of the fit (losses per epoch, seconds).
    """
    torch = require("torch", "train-cnn", "training the network")
    nn = torch.nn
    torch.manual_seed(config.seed)
    torch.set_num_threads(config.threads)
    rng = np.random.default_rng(config.seed)
    x_all = torch.from_numpy(_halve(np.asarray(patches, np.uint8))).permute(0, 3, 1, 2).contiguous()  # (N, 3, 32, 32), 0..255
    y_all = torch.from_numpy(np.asarray(labels, np.float32))
    off = np.asarray(offsets, np.float32)
    has_box = torch.from_numpy(np.all(np.isfinite(off), axis=1))
    t_all = torch.from_numpy(np.nan_to_num(off))
    model = network(config.channels)
    n = len(y_all)
    steps = config.epochs * ((n + config.batch - 1) // config.batch)
    opt = torch.optim.AdamW(model.parameters(), lr=config.learning_rate, weight_decay=1e-4)
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=config.learning_rate, total_steps=steps, pct_start=0.15)
    pos_weight = torch.tensor(float((y_all == 0).sum()) / max(1.0, float((y_all == 1).sum())))
    bce = nn.BCEWithLogitsLoss(pos_weight=pos_weight)
    record = {"epochs": [], "n": int(n), "n_vehicles": int((y_all == 1).sum()), "n_box_targets": int(has_box.sum())}
    t0 = time.perf_counter()
    model.train()
    for epoch in range(config.epochs):
        perm = torch.from_numpy(rng.permutation(n))
        total, seen = 0.0, 0
        for i in range(0, n, config.batch):
            idx = perm[i : i + config.batch]
            x, t = _augment(torch, x_all[idx].clone(), t_all[idx].clone(), rng)
            out = model((x / 255.0 - MEAN) / STD)[:, :, 0, 0]
            y = y_all[idx]
            loss = bce(out[:, 0], y)
            hb = has_box[idx]
            if hb.any():
                loss = loss + config.box_weight * nn.functional.smooth_l1_loss(out[hb, 1:], t[hb], beta=0.05)
            opt.zero_grad()
            loss.backward()
            opt.step()
            sched.step()
            total += float(loss.detach()) * len(idx)
            seen += len(idx)
        record["epochs"].append(round(total / seen, 5))
        if progress:
            print(f"epoch {epoch + 1}/{config.epochs}: loss {total / seen:.4f} ({time.perf_counter() - t0:.0f} s)", flush=True)
    record["seconds"] = round(time.perf_counter() - t0, 1)
    return export(model), record


def network(channels=(16, 32, 32, 32)):
    """The network of :class:`~vehicle_detection.convnet.ConvNet` in PyTorch, with batch
    normalisation after each convolution but the last (an ``nn.Sequential``; input (B, 3, 32, 32),
    the half-resolution pixels scaled as :meth:`ConvNet.forward` scales them)."""
    nn = require("torch", "train-cnn", "training the network").nn
    c1, c2, c3, c4 = channels

    def block(cin, cout, k, pad):
        return [nn.Conv2d(cin, cout, k, padding=pad), nn.BatchNorm2d(cout), nn.ReLU()]

    return nn.Sequential(
        *block(3, c1, 3, 1), nn.MaxPool2d(2),
        *block(c1, c2, 3, 1), nn.MaxPool2d(2),
        *block(c2, c3, 3, 1),
        *block(c3, c4, (8, 1), 0),
        *block(c4, c4, (1, 8), 0),
        nn.Conv2d(c4, N_OUT, 1),
    )


def _augment(torch, x, t, rng, *, zoom: float = 0.12, shift: float = 0.08, blur: float = 0.3):
    """Random mirror, zoom, shift, blur and light for a batch ``(B, 3, 32, 32)`` of 0..255
    pixels; the edge offsets ``t`` (B, 4) follow the mirror, zoom and shift."""
    b = x.shape[0]
    flip = torch.from_numpy(rng.random(b) < 0.5)
    x[flip] = x[flip].flip(3)
    t[flip] = torch.stack([-t[flip][:, 2], t[flip][:, 1], -t[flip][:, 0], t[flip][:, 3]], dim=1)
    if zoom or shift:
        # content scaled by z about the window's centre and moved by (dx, dy) window sides
        z = np.exp(rng.uniform(-zoom, zoom, b)).astype(np.float32)
        d = rng.uniform(-shift, shift, (b, 2)).astype(np.float32)
        theta = np.zeros((b, 2, 3), np.float32)
        theta[:, 0, 0] = theta[:, 1, 1] = 1 / z
        theta[:, :, 2] = -2 * d / z[:, None]
        grid = torch.nn.functional.affine_grid(torch.from_numpy(theta), list(x.shape), align_corners=False)
        x = torch.nn.functional.grid_sample(x, grid, mode="bilinear", padding_mode="reflection", align_corners=False)
        zt, dt = torch.from_numpy(z)[:, None], torch.from_numpy(d)
        lo = (t[:, :2] - 0.5) * zt + 0.5 + dt  # left, top edges in window units
        hi = (t[:, 2:] + 0.5) * zt + 0.5 + dt  # right, bottom edges
        t = torch.cat([lo, hi - 1.0], dim=1)
    if blur:
        k = torch.tensor([0.25, 0.5, 0.25])
        kernel = (k[:, None] * k[None, :]).expand(3, 1, 3, 3)
        soft = torch.from_numpy(rng.random(b) < blur)
        if soft.any():
            x[soft] = torch.nn.functional.conv2d(torch.nn.functional.pad(x[soft], (1, 1, 1, 1), mode="replicate"), kernel, groups=3)
    x = x / 255.0
    grey = x.mean(dim=1, keepdim=True)
    sat = torch.from_numpy(rng.uniform(0.3, 1.6, (b, 1, 1, 1)).astype(np.float32))
    sat[torch.from_numpy(rng.random(b) < 0.1)] = 0.0
    x = grey + (x - grey) * sat
    gain = torch.from_numpy(rng.uniform(0.8, 1.2, (b, 3, 1, 1)).astype(np.float32))
    x = x * gain
    contrast = torch.from_numpy(rng.uniform(0.6, 1.4, (b, 1, 1, 1)).astype(np.float32))
    mean = x.mean(dim=(1, 2, 3), keepdim=True)
    x = (x - mean) * contrast + mean
    x = x * torch.from_numpy(rng.uniform(0.5, 1.5, (b, 1, 1, 1)).astype(np.float32))
    x = x.clamp(0.0, 1.0) ** torch.from_numpy(np.exp(rng.uniform(-0.4, 0.4, (b, 1, 1, 1))).astype(np.float32))
    x = x + torch.randn_like(x) * torch.from_numpy(rng.uniform(0, 0.03, (b, 1, 1, 1)).astype(np.float32))
    return (x.clamp(0.0, 1.0) * 255.0, t)


def export(model) -> ConvNet:
    """A trained :func:`network` as a :class:`~vehicle_detection.convnet.ConvNet`: batch
    normalisation folded into each convolution, weights laid out (kh, kw, c_in, c_out)."""
    import torch

    model.eval()
    layers = list(model)
    weights, biases = [], []
    i = 0
    with torch.no_grad():
        while i < len(layers):
            conv = layers[i]
            if not isinstance(conv, torch.nn.Conv2d):
                i += 1
                continue
            w = conv.weight.detach().clone()
            b = conv.bias.detach().clone()
            if i + 1 < len(layers) and isinstance(layers[i + 1], torch.nn.BatchNorm2d):
                bn = layers[i + 1]
                g = bn.weight / torch.sqrt(bn.running_var + bn.eps)
                w = w * g[:, None, None, None]
                b = (b - bn.running_mean) * g + bn.bias
            weights.append(w.permute(2, 3, 1, 0).numpy().astype(np.float32))
            biases.append(b.numpy().astype(np.float32))
            i += 1
    return ConvNet(tuple(weights), tuple(biases))


def samples_from(datasets: Iterable) -> FrameSamples:
    """Archive patches (:class:`~vehicle_detection.training.data.Dataset`) as samples without box targets."""
    parts: list[FrameSamples] = []
    for d in datasets:
        parts.append(FrameSamples(d.images, d.labels.astype(np.int8), np.full((len(d), 4), np.nan, np.float32), d.sources))
    return FrameSamples.empty().concatenate(*parts)


def with_convnet(model, patches, annotations: Sequence[Annotations], config: ConvNetTraining = ConvNetTraining(), *,
                 rounds: int = 2, progress: bool = False):
    """``model`` with a window-scoring network trained on ``patches`` and labelled frames.

    Parameters
    ----------
    model : VehicleClassifier
        The model the network joins (its SVM stays, unused by the search).
    patches : Dataset
        The archives' patches (and any extra negatives), without box targets.
    annotations : sequence of Annotations
        The training cameras' labelled frames: their cars' windows (with box targets) and
        background windows (:func:`frame_samples`), and in each later round the windows the
        previous round's network scores highest off every car (:func:`hard_windows`).
    rounds : int
        Training rounds (>= 1).

    Returns
    -------
    VehicleClassifier
        With ``convnet`` and the network's detector settings (:func:`detector_settings`); no
        box refinement (the network gives each window's edges). ``metrics["convnet"]`` records
        the fit.
    """
    if rounds < 1:
        raise ValueError(f"rounds must be >= 1; got {rounds}")
    t = time.perf_counter()
    data = samples_from([patches]).concatenate(frame_samples(annotations, config))
    settings = detector_settings(model.detector_config, wide=config.wide)
    # hard negatives are mined at the base plan's scales (and the wide windows' where there are any)
    mining = detector_settings(model.detector_config, small=False, large=False, wide=config.wide).plan
    record = {}
    net, hard = None, 0
    for r in range(rounds):
        if r:
            extra = hard_windows(net, annotations, mining)
            data = data.concatenate(extra)
            hard += len(extra)
            if progress:
                print(f"round {r + 1}: {len(extra)} hard negatives", flush=True)
        net, record = fit_convnet(data.patches, data.labels, data.offsets, config, progress=progress)
    record.update(rounds=rounds, hard_negatives=hard, total_seconds=round(time.perf_counter() - t, 1),
                  channels=list(config.channels), training_cameras=sorted({a.camera or "unnamed" for a in annotations}))
    return model.replace(convnet=net, box_regressor=None, detector_config=settings,
                         metrics={**model.metrics, "convnet": record})
