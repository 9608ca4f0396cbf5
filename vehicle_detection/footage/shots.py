"""Cuts between shots: where edited footage jumps to another scene between two frames.

Dashcam compilations, news clips and replays cut from one shot to another. A vehicle tracked
before a cut is not the one at its place after it, so at a cut the tracker forgets its heat and
its tracks (:meth:`~vehicle_detection.tracker.Tracker.cut`); track ids go on.

A cut is found from consecutive frames' thumbnails (:data:`THUMBNAIL` pixels, each the mean of
a block of the frame, so the size of the frame does not matter): their mean absolute difference,
in levels of 0 to 255, once the second is scaled to the first's mean brightness, is a frame's
*change* (so a sudden change of light, a bridge's shadow or the camera's exposure, is not a
cut). A frame is a cut when its change exceeds
:attr:`ShotCuts.threshold` and :attr:`ShotCuts.ratio` times the median change of the
:attr:`ShotCuts.memory` frames before it: a single-frame jump, not the steady large changes of
fast or low-frame-rate footage.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from .._settings import JsonSettings, number_in

__all__ = ["THUMBNAIL", "ShotCuts", "frame_change", "next_shot", "thumbnail"]

THUMBNAIL = (48, 27)
"""(width, height) of the thumbnails frames are compared by."""


@dataclass(frozen=True)
class ShotCuts(JsonSettings):
    """When a frame starts a new shot.

    Parameters
    ----------
    threshold : float, default 30.0
        Least change (mean absolute difference of the thumbnails, levels of 0 to 255) of a cut,
        > 0.
    ratio : float, default 3.0
        A cut's change is also more than this many times the median change of the frames
        before it, >= 1.
    memory : int, default 8
        How many of the last frames' changes that median is taken over, >= 1.

    Raises
    ------
    ValueError
        If a value is out of range; the message names the field.
    """

    threshold: float = 30.0
    ratio: float = 3.0
    memory: int = 8

    def __post_init__(self) -> None:
        object.__setattr__(self, "threshold", number_in(self, "threshold", 0.0))
        object.__setattr__(self, "ratio", number_in(self, "ratio", 1.0, low_in=True))
        m = self.memory
        if isinstance(m, bool) or not isinstance(m, (int, np.integer)) or m < 1:
            raise ValueError(f"ShotCuts.memory must be an integer >= 1; got {m!r}")
        object.__setattr__(self, "memory", int(m))


def thumbnail(frame: np.ndarray) -> np.ndarray:
    """The frame's thumbnail: float32 ``(27, 48, 3)`` (:data:`THUMBNAIL`), each pixel the mean of
    a block of the frame, sampled every few pixels (at least 4 x 4 samples a block).

    Parameters
    ----------
    frame : ndarray of uint8, shape (H, W, 3)
        An RGB frame.
    """
    w, h = THUMBNAIL
    step = max(1, min(frame.shape[0] // (4 * h), frame.shape[1] // (4 * w)))
    sampled = np.ascontiguousarray(frame[::step, ::step])  # OpenCV's block means are slow at fractional ratios
    return cv2.resize(sampled, THUMBNAIL, interpolation=cv2.INTER_AREA).astype(np.float32)


def frame_change(a: np.ndarray, b: np.ndarray) -> float:
    """Mean absolute difference of two thumbnails (:func:`thumbnail`), in levels of 0 to 255,
    ``b`` scaled to ``a``'s mean brightness first (as it is when either is black)."""
    mean_a, mean_b = float(a.mean()), float(b.mean())
    if min(mean_a, mean_b) >= 1.0:
        b = b * np.float32(mean_a / mean_b)
    return float(np.abs(a - b).mean())


def next_shot(
    frame: np.ndarray, previous: np.ndarray | None, changes: tuple[float, ...], rule: ShotCuts
) -> tuple[bool, np.ndarray, tuple[float, ...]]:
    """Whether ``frame`` starts a new shot, given the frame before it.

    Parameters
    ----------
    frame : ndarray of uint8, shape (H, W, 3)
        The frame.
    previous : ndarray or None
        The thumbnail of the frame before it (None: this is the first frame; no cut).
    changes : tuple of float
        The changes of the frames before it, oldest first (at most ``rule.memory``).
    rule : ShotCuts

    Returns
    -------
    cut : bool
        Whether the frame is a cut.
    thumb : ndarray
        The frame's thumbnail (the next call's ``previous``).
    changes : tuple of float
        The next call's ``changes``: this frame's change added, the last ``rule.memory`` kept.
        A cut's change is kept too, so that footage changing this much every frame (a time
        lapse) is not cut at every frame.
    """
    thumb = thumbnail(frame)
    if previous is None or previous.shape != thumb.shape:
        return False, thumb, ()
    change = frame_change(previous, thumb)
    typical = float(np.median(changes)) if changes else 0.0
    cut = change > rule.threshold and change > rule.ratio * typical
    return cut, thumb, (tuple(changes) + (change,))[-rule.memory :]
