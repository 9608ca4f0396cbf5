"""Training: feature extraction, honest held-out accuracies, the final fit, and parameter sweeps.

:func:`train` turns a :class:`~vehicle_detection.training.data.Dataset` into a
:class:`~vehicle_detection.classifier.VehicleClassifier` (the model type, its file format and its
scoring live in :mod:`vehicle_detection.classifier`); :func:`with_box_refinement` adds the box
refinement learned from labelled frames; :func:`sweep` compares feature configurations on the
random and grouped splits (:func:`split_indices`).
"""

from __future__ import annotations

import dataclasses
import itertools
import time
from collections.abc import Iterator
from contextlib import closing

import numpy as np
from joblib import Parallel, delayed
from sklearn.metrics import accuracy_score, confusion_matrix, precision_score, recall_score
from sklearn.model_selection import GroupShuffleSplit, train_test_split

from ..classifier import DEFAULT_C, VehicleClassifier
from ..errors import InputError
from ..features import FeatureConfig, extract_features
from ..geometry import mirror_image
from ..refine import REFINE_ALPHA, fit_box_regressor
from .augment import AugmentConfig, augment as augment_patches
from .data import Dataset, check_split_sizes
from .mining import labelled_frames

__all__ = ["split_indices", "with_copies", "train", "with_box_refinement", "sweep", "sweep_configs"]


def split_indices(labels, groups=None, *, test_size: float = 0.2, random_state: int = 0):
    """Train/test indices of a randomised split; grouped when ``groups`` is given.

    With ``groups`` no group is on both sides (:class:`~sklearn.model_selection.GroupShuffleSplit`);
    without, the split is stratified by label.

    Returns
    -------
    train, test : ndarray of int
    """
    idx = np.arange(len(labels))
    if groups is None:
        return train_test_split(idx, test_size=test_size, random_state=random_state, shuffle=True, stratify=labels)
    gss = GroupShuffleSplit(n_splits=1, test_size=test_size, random_state=random_state)
    return next(gss.split(idx, labels, groups))


def with_copies(train_index, origin, n: int) -> np.ndarray:
    """A split's training indexes with those of the augmented copies of its patches.

    Parameters
    ----------
    train_index : ndarray of int
        Training-side indexes into the ``n`` original patches.
    origin : ndarray of int, shape (M,)
        Source patch of each augmented copy; copy ``j`` is row ``n + j`` of the features.
    n : int
        Number of original patches.

    Returns
    -------
    ndarray of int64
        ``train_index`` followed by ``n + j`` for every copy ``j`` whose source is in it.
    """
    train_index = np.asarray(train_index, dtype=np.int64)
    on_train = np.zeros(n, bool)
    on_train[train_index] = True
    return np.concatenate([train_index, n + np.flatnonzero(on_train[np.asarray(origin, dtype=np.int64)])])


def _scores(y_true, y_pred) -> dict:
    tn, fp, fn, tp = confusion_matrix(y_true, y_pred, labels=[0, 1]).ravel()
    return {
        "accuracy": float(accuracy_score(y_true, y_pred)),
        "precision": float(precision_score(y_true, y_pred, zero_division=0)),
        "recall": float(recall_score(y_true, y_pred, zero_division=0)),
        "confusion": {"tn": int(tn), "fp": int(fp), "fn": int(fn), "tp": int(tp)},
    }


def _evaluate_split(features, labels, config, train_idx, test_idx, C):
    t = time.perf_counter()
    model = VehicleClassifier.fit(features[train_idx], labels[train_idx], config, C=C)
    fit_s = time.perf_counter() - t
    pred = model.predict(features[test_idx])
    out = _scores(labels[test_idx], pred)
    out.update(n_train=int(len(train_idx)), n_test=int(len(test_idx)), fit_seconds=round(fit_s, 3))
    return out


def train(
    dataset: Dataset,
    config: FeatureConfig = FeatureConfig(),
    *,
    C: float = DEFAULT_C,
    test_size: float = 0.2,
    random_state: int = 0,
    evaluate: bool = True,
    n_jobs: int = 2,
    augment: AugmentConfig | None = None,
) -> VehicleClassifier:
    """Extract features, report honest accuracies, and fit the final model on every patch.

    Two held-out evaluations are run (in parallel with ``n_jobs``): a randomised stratified
    80/20 split, and a grouped 80/20 split in which no group of
    :attr:`~vehicle_detection.training.data.Dataset.groups` (GTI time-series blocks, byte-identical
    files) is on both sides. The final model is then fitted on all patches.

    With ``augment`` (``copies`` > 0), each patch gets ``augment.copies`` augmented copies
    (:func:`~vehicle_detection.training.augment.augment`, drawn from ``random_state``) with its
    label. A copy is trained on only where its source patch is: on the training side of each
    split (so a grouped split has no copy of a test-side patch, or of its group, in training),
    and in the final fit. The test sides hold the original patches only. The splits are then
    fitted one after the other (whatever ``n_jobs``), to bound the memory.

    Returns
    -------
    VehicleClassifier
        With ``metrics``: ``random_split`` and ``grouped_split`` (accuracy, precision, recall,
        confusion, n_train (augmented copies included), n_test, n_augmented (copies trained
        on), fit_seconds), ``feature_seconds`` and ``fit_seconds`` for all patches (copies
        included), ``n_images`` (originals), ``n_features``, ``C``, and ``augment`` (the
        :class:`AugmentConfig` fields, ``n_copies``, ``seconds``).
    """
    labels = np.asarray(dataset.labels)
    splits = {}
    if evaluate:  # too small a data set is refused here, before any work, not by scikit-learn
        check_split_sizes(labels, dataset.groups, test_size=test_size)
        splits = {
            "random_split": split_indices(labels, test_size=test_size, random_state=random_state),
            "grouped_split": split_indices(labels, dataset.groups, test_size=test_size, random_state=random_state),
        }
    elif len(np.unique(labels)) < 2:
        raise InputError(f"dataset: training needs images of both classes, got only label(s) {np.unique(labels).tolist()}")
    n = len(labels)
    images, origin, aug_metrics = dataset.images, np.zeros(0, np.int64), {}
    if augment is not None and augment.copies > 0:
        t = time.perf_counter()
        copies, origin = augment_patches(dataset.images, augment, np.random.default_rng(random_state))
        images = np.concatenate([dataset.images, copies])
        labels = np.concatenate([labels, labels[origin]])
        del copies
        aug_metrics = {"augment": {**augment.to_dict(), "n_copies": int(len(origin)), "seconds": round(time.perf_counter() - t, 3)}}
    extract_features(dataset.images[:2], config)  # compile the kernels outside the timing
    t = time.perf_counter()
    features = extract_features(images, config)
    feature_s = time.perf_counter() - t
    del images
    metrics = {}
    if evaluate:
        # The copies multiply each fit's memory (LinearSVC holds a float64 copy of its rows and
        # liblinear another): with them the two splits are fitted one after the other.
        results = Parallel(n_jobs=1 if len(origin) else n_jobs, backend="threading")(
            delayed(_evaluate_split)(features, labels, config, with_copies(tr, origin, n), te, C) for tr, te in splits.values()
        )
        for result, (tr, _) in zip(results, splits.values()):
            result["n_augmented"] = result["n_train"] - int(len(tr))
        metrics.update(zip(splits, results))
    t = time.perf_counter()
    model = VehicleClassifier.fit(features, labels, config, C=C)
    fit_s = time.perf_counter() - t
    metrics.update(
        **aug_metrics,
        feature_seconds=round(feature_s, 3),
        fit_seconds=round(fit_s, 3),
        n_images=int(n),
        n_features=int(config.n_features),
        C=C,
        test_size=test_size,
        random_state=random_state,
    )
    return model.replace(metrics=metrics)


def _searched_frames(model: VehicleClassifier, annotations, flip: bool = False) -> Iterator[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """``(frame, cars, windows)`` of every labelled frame: the windows ``model``'s detector
    accepts there (none searched in a frame without cars). A video is searched at the horizon,
    bars and light measured on its first frames, as ``detect`` starts it; unlike ``detect``, they
    are not measured again after a cut between shots. An image is searched on its own.
    ``flip``: the frames (and their labels) flipped left to right, searched as right-hand
    traffic (:func:`~vehicle_detection.training.mining.labelled_frames`)."""
    from ..detector import Detector  # the search, only when labels are given
    from ..io.video import read_frames

    for ann in annotations:
        detector = Detector(model, model.detector_config.replace(traffic="right"))
        source = ann.source
        if source is not None and source.is_file():
            with closing(read_frames(source)) as frames:
                pictures = map(mirror_image, frames) if flip else frames
                detector, _ = detector.for_footage(pictures, detector.new_tracker())
        for _, frame, labels in labelled_frames(ann, flip=flip):
            yield frame, labels.cars, detector.windows(frame).xyxy if len(labels.cars) else np.zeros((0, 4), np.int64)


#: How the heat of windows that carry their own boxes (the box refinement's, or the network's edge
#: offsets) becomes one box per vehicle: blobs split where their windows' boxes form clusters at
#: this IoU, and each box moved this far towards the mean of its windows' boxes.
CLUSTER_IOU, BOX_VOTE = 0.3, 0.5


def boxed_windows_tracker(tracker, *, cluster_iou: float = CLUSTER_IOU, box_vote: float = BOX_VOTE):
    """``tracker`` (a :class:`~vehicle_detection.tracker.TrackerConfig`) for windows that carry
    their own boxes: heat on each box as it is (no fixed window inset), blobs split at
    ``cluster_iou``, boxes voted ``box_vote`` of the way to their windows' mean box."""
    return dataclasses.replace(tracker, window_inset=(0.0, 0.0, 0.0, 0.0), cluster_iou=cluster_iou, box_vote=box_vote)


def with_box_refinement(
    model: VehicleClassifier, annotations, *, alpha: float = REFINE_ALPHA, cluster_iou: float = CLUSTER_IOU, box_vote: float = BOX_VOTE,
    hot_iou: float | None = 0.5, mirror: bool = False, traffic: str | None = None,
) -> VehicleClassifier:
    """``model`` with a box refinement learned from labelled frames (:mod:`~vehicle_detection.refine`).

    Heat then goes to each window's refined box as it is (no fixed window inset), and blobs
    whose refined boxes form several clusters at ``cluster_iou`` are split, one box per vehicle
    (:func:`~vehicle_detection.heatmap.split_blobs`); each box then moves ``box_vote`` of the
    way to the mean of its windows' refined boxes (:func:`~vehicle_detection.heatmap.vote_boxes`).

    Parameters
    ----------
    annotations : sequence of Annotations
        Labelled frames; frames you score later must not be among them.
    alpha : float
        Ridge penalty on standardised features (:data:`~vehicle_detection.refine.REFINE_ALPHA` by default): larger values
        learn less of the labelled cars' own shapes.
    cluster_iou, box_vote : float
        Saved in the detector's tracker settings (:class:`~vehicle_detection.tracker.TrackerConfig`).
    hot_iou : float or None
        The windows ``model``'s search accepts in the labelled frames that overlap a labelled
        vehicle at this IoU or more, and that jittering never draws, are learned from too
        (:func:`~vehicle_detection.refine.fit_box_regressor`): the rear of a car seen at an
        angle, for one. None: only windows jittered around the vehicles (the embedded model
        before 2026-11-26).
    mirror : bool
        Learn from the frames flipped left to right too
        (:func:`~vehicle_detection.refine.fit_box_regressor`): a refinement for left-hand and
        right-hand traffic alike.
    traffic : {"right", "left"} or None
        The traffic of the labelled frames (None: ``model``'s setting,
        :attr:`~vehicle_detection.config.DetectorConfig.traffic`). Frames of left-hand traffic
        are learned flipped left to right, as the detector searches them, and the model is saved
        for left-hand traffic.
    """
    if hot_iou is not None and not 0 < hot_iou <= 1:
        raise ValueError(f"hot_iou must be in (0, 1] or None; got {hot_iou!r}")
    cfg = model.detector_config
    cfg = cfg.replace(tracker=boxed_windows_tracker(cfg.tracker, cluster_iou=cluster_iou, box_vote=box_vote),
                      traffic=cfg.traffic if traffic is None else traffic)
    flip = cfg.traffic == "left"
    t = time.perf_counter()
    if hot_iou is None:
        samples, accepted = ((frame, labels.cars) for ann in annotations for _, frame, labels in labelled_frames(ann, flip=flip)), {}
    else:
        samples, accepted = _searched_frames(model, annotations, flip), {"hot_iou": hot_iou}
    regressor = fit_box_regressor(samples, model.config, alpha=alpha, reference_height=cfg.plan.reference_height, mirror=mirror, **accepted)
    metrics = {**model.metrics, "box_refinement": {"alpha": alpha, "hot_iou": hot_iou, "mirror": mirror, "seconds": round(time.perf_counter() - t, 3),
                                                    "labels": [str(a.path) for a in annotations]}}
    return model.replace(box_regressor=regressor, detector_config=cfg, metrics=metrics)


# --- parameter sweep ---------------------------------------------------------------------------


def sweep_configs(
    color_spaces=("YCrCb", "YUV", "HLS", "LUV"),
    hog_channels=((0, 1, 2),),
    orientations=(9, 16),
    pixels_per_cell=(8, 16),
    cells_per_block=(2,),
    color_features=((16, 32), (0, 0)),
    signed=(True,),
    hog_sqrt=(True,),
) -> list[FeatureConfig]:
    """The product of the given choices as :class:`FeatureConfig` objects.

    ``color_features`` lists ``(spatial_size, hist_bins)`` pairs; ``(0, 0)`` is HOG only.
    """
    return [
        FeatureConfig(
            color_space=cs, hog_channels=ch, orientations=o, pixels_per_cell=p, cells_per_block=b,
            signed=sg, hog_sqrt=sq, spatial_size=s, hist_bins=h,
        )
        for cs, ch, o, p, b, (s, h), sg, sq in itertools.product(
            color_spaces, hog_channels, orientations, pixels_per_cell, cells_per_block, color_features, signed, hog_sqrt
        )
    ]


def _sweep_one(images, labels, groups, config, C, test_size, random_state):
    t = time.perf_counter()
    feats = extract_features(images, config)
    feature_s = time.perf_counter() - t
    row = {k: (list(v) if isinstance(v, tuple) else v) for k, v in dataclasses.asdict(config).items()}
    row.update(n_features=config.n_features, feature_seconds=round(feature_s, 3))
    for name, g in (("random", None), ("grouped", groups)):
        tr, te = split_indices(labels, g, test_size=test_size, random_state=random_state)
        res = _evaluate_split(feats, labels, config, tr, te, C)
        row[f"{name}_accuracy"] = res["accuracy"]
        row[f"{name}_fit_seconds"] = res["fit_seconds"]
    return row


def sweep(
    dataset: Dataset,
    configs: list[FeatureConfig],
    *,
    C: float = DEFAULT_C,
    test_size: float = 0.2,
    random_state: int = 0,
    n_jobs: int = 2,
) -> list[dict]:
    """Score each feature configuration on the random and grouped splits, in parallel.

    Returns
    -------
    list of dict
        One row per config: its fields, ``n_features``, ``feature_seconds``,
        ``random_accuracy``, ``grouped_accuracy`` and the fit times; sorted by
        ``grouped_accuracy``, best first.
    """
    check_split_sizes(dataset.labels, dataset.groups, test_size=test_size)  # before any work
    rows = Parallel(n_jobs=n_jobs)(
        delayed(_sweep_one)(dataset.images, dataset.labels, dataset.groups, cfg, C, test_size, random_state) for cfg in configs
    )
    return sorted(rows, key=lambda r: -r["grouped_accuracy"])
