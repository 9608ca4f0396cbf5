"""Multi-object tracking metrics: CLEAR MOT (MOTA), identity (IDF1) and HOTA.

The definitions follow the reference implementation of the MOTChallenge benchmarks (TrackEval,
Luiten et al., "HOTA: A Higher Order Metric for Evaluating Multi-Object Tracking", IJCV 2021),
with IoU as the similarity of two boxes:

* **MOTA** ``= 1 - (FN + FP + IDSW) / n_gt``: per frame, ground-truth and tracker boxes are
  matched one to one among pairs with IoU >= 0.5, preferring the pairs matched in the previous
  frame; an identity switch is a ground-truth object matched to another tracker id than the last
  time it was matched.
* **IDF1** ``= IDTP / (IDTP + (IDFN + IDFP) / 2)``: ground-truth ids and tracker ids are matched
  one to one over the whole sequence, maximising the frames in which a matched pair overlaps
  with IoU >= 0.5 (IDTP).
* **HOTA** is the mean over localisation thresholds ``alpha = 0.05, 0.10, ..., 0.95`` of
  ``sqrt(DetA * AssA)``: per frame, boxes are matched maximising IoU weighted by how well the two
  ids align over the whole sequence; a match counts at ``alpha`` if its IoU >= alpha. DetA is
  ``TP / (TP + FN + FP)``, AssA the mean over true positives of the association IoU
  ``TPA / (TPA + FNA + FPA)`` of their ids.

The library's own tracker and this module are not used to define each other: the tests check
these functions on sequences whose scores are worked out by hand.

A sequence is a list of frames; each frame is ``(gt_ids, gt_boxes, tracker_ids, tracker_boxes)``
with ids as integer arrays ``(n,)`` and boxes as ``(n, 4)`` ``[x1, y1, x2, y2]`` arrays.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from ..geometry import box_iou

__all__ = ["TrackingScores", "tracking_scores"]

_EPS = np.finfo(float).eps
ALPHAS = np.arange(0.05, 0.99, 0.05)
Frame = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]


@dataclass(frozen=True)
class TrackingScores:
    """Tracking metrics of one sequence (see the module docstring).

    Attributes
    ----------
    mota, idf1, hota : float
    deta, assa : float
        HOTA's detection and association accuracy, averaged over the thresholds.
    id_switches : int
    n_gt, n_tracker : int
        Ground-truth and tracker boxes over all frames.
    n_frames : int
    """

    mota: float
    idf1: float
    hota: float
    deta: float
    assa: float
    id_switches: int
    n_gt: int
    n_tracker: int
    n_frames: int

    def as_dict(self) -> dict[str, float | int]:
        return dict(vars(self))


def _relabel(frames: Sequence[Frame]) -> tuple[list[tuple[np.ndarray, np.ndarray, np.ndarray]], int, int]:
    """Ids as 0..n-1 per side, and each frame's IoU matrix."""
    gt_map: dict[int, int] = {}
    tr_map: dict[int, int] = {}
    out = []
    for gt_ids, gt_boxes, tr_ids, tr_boxes in frames:
        g = np.array([gt_map.setdefault(int(i), len(gt_map)) for i in np.asarray(gt_ids).reshape(-1)], np.intp)
        t = np.array([tr_map.setdefault(int(i), len(tr_map)) for i in np.asarray(tr_ids).reshape(-1)], np.intp)
        sim = box_iou(gt_boxes, tr_boxes)
        if sim.shape != (len(g), len(t)):
            raise ValueError("each frame needs one id per box on both sides")
        out.append((g, t, sim))
    return out, len(gt_map), len(tr_map)


def _clear(frames, threshold: float = 0.5) -> tuple[float, int]:
    n_gt = sum(len(g) for g, _, _ in frames)
    tp = fn = fp = idsw = 0
    last_match: dict[int, int] = {}  # gt id -> tracker id it was last matched to
    prev_pairs: set[tuple[int, int]] = set()
    for g, t, sim in frames:
        pairs: set[tuple[int, int]] = set()
        if len(g) and len(t):
            cont = np.array([[(gi, ti) in prev_pairs for ti in t] for gi in g], dtype=float)
            score = np.where(sim >= threshold - _EPS, 1000.0 * cont + sim, 0.0)
            rows, cols = linear_sum_assignment(-score)
            keep = score[rows, cols] > 0
            for r, c in zip(rows[keep].tolist(), cols[keep].tolist()):
                gi, ti = int(g[r]), int(t[c])
                if gi in last_match and last_match[gi] != ti:
                    idsw += 1
                last_match[gi] = ti
                pairs.add((gi, ti))
        tp += len(pairs)
        fn += len(g) - len(pairs)
        fp += len(t) - len(pairs)
        prev_pairs = pairs
    mota = 1.0 - (fn + fp + idsw) / max(1, n_gt) if n_gt else 0.0
    return mota, idsw


def _identity(frames, n_gt_ids: int, n_tr_ids: int, threshold: float = 0.5) -> float:
    n_gt = sum(len(g) for g, _, _ in frames)
    n_tr = sum(len(t) for _, t, _ in frames)
    if n_gt + n_tr == 0:
        return 0.0
    overlap = np.zeros((n_gt_ids, n_tr_ids))
    for g, t, sim in frames:
        r, c = np.nonzero(sim >= threshold - _EPS)
        np.add.at(overlap, (g[r], t[c]), 1)
    rows, cols = linear_sum_assignment(-overlap) if overlap.size else (np.zeros(0, int), np.zeros(0, int))
    idtp = float(overlap[rows, cols].sum())
    return idtp / (idtp + 0.5 * (n_gt - idtp) + 0.5 * (n_tr - idtp))


def _hota(frames, n_gt_ids: int, n_tr_ids: int) -> tuple[float, float, float]:
    n_gt = sum(len(g) for g, _, _ in frames)
    n_tr = sum(len(t) for _, t, _ in frames)
    if n_gt == 0 or n_tr == 0:
        return 0.0, 0.0, 0.0
    # Global alignment of ids: soft counts of how much each pair overlaps over the sequence.
    potential = np.zeros((n_gt_ids, n_tr_ids))
    gt_count = np.zeros((n_gt_ids, 1))
    tr_count = np.zeros((1, n_tr_ids))
    for g, t, sim in frames:
        denom = sim.sum(0)[None, :] + sim.sum(1)[:, None] - sim
        sim_iou = np.zeros_like(sim)
        np.divide(sim, denom, out=sim_iou, where=denom > _EPS)
        np.add.at(potential, (g[:, None], t[None, :]), sim_iou)
        np.add.at(gt_count, (g, 0), 1)
        np.add.at(tr_count, (0, t), 1)
    alignment = potential / (gt_count + tr_count - potential)

    tp = np.zeros(len(ALPHAS))
    matches = np.zeros((len(ALPHAS), n_gt_ids, n_tr_ids))
    for g, t, sim in frames:
        if not (len(g) and len(t)):
            continue
        rows, cols = linear_sum_assignment(-(alignment[g[:, None], t[None, :]] * sim))
        s = sim[rows, cols]
        for a, alpha in enumerate(ALPHAS):
            ok = s >= alpha - _EPS
            tp[a] += ok.sum()
            np.add.at(matches[a], (g[rows[ok]], t[cols[ok]]), 1)
    deta = tp / (n_gt + n_tr - tp)
    assa = np.zeros(len(ALPHAS))
    for a in range(len(ALPHAS)):
        m = matches[a]
        ass_iou = m / np.maximum(1, gt_count + tr_count - m)
        assa[a] = (m * ass_iou).sum() / max(1.0, tp[a])
    hota = np.sqrt(deta * assa)
    return float(hota.mean()), float(deta.mean()), float(assa.mean())


def tracking_scores(frames: Sequence[Frame]) -> TrackingScores:
    """MOTA, IDF1 and HOTA of a tracker over a sequence of frames.

    Parameters
    ----------
    frames : sequence of (gt_ids, gt_boxes, tracker_ids, tracker_boxes)
        Every frame of the stretch, in order (frames without boxes included, as empty arrays).

    Returns
    -------
    TrackingScores

    Examples
    --------
    >>> box = np.array([[0, 0, 10, 10]])
    >>> perfect = [(np.array([1]), box, np.array([7]), box)] * 4
    >>> s = tracking_scores(perfect)
    >>> round(s.mota, 3), round(s.idf1, 3), round(s.hota, 3)
    (1.0, 1.0, 1.0)
    """
    rel, n_gt_ids, n_tr_ids = _relabel(frames)
    mota, idsw = _clear(rel)
    hota, deta, assa = _hota(rel, n_gt_ids, n_tr_ids)
    return TrackingScores(
        mota=float(mota),
        idf1=float(_identity(rel, n_gt_ids, n_tr_ids)),
        hota=hota,
        deta=deta,
        assa=assa,
        id_switches=int(idsw),
        n_gt=int(sum(len(g) for g, _, _ in rel)),
        n_tracker=int(sum(len(t) for _, t, _ in rel)),
        n_frames=len(rel),
    )
