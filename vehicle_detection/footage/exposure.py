"""Dark footage brightened before the search: dusk, dark cameras, underexposed video.

The classifier learned from daylight patches. Its HOG blocks are normalised and hardly change
with the light, but its spatial bins and colour histograms read brightness as it is, so in dark
footage a car's margin falls below the threshold. A picture is *dark* when the 90th percentile
of the luminance of its lower half (the road and the cars on it; bright sky above does not count,
and lane markings and car bodies make the percentile high in daylight) is below
:attr:`Exposure.dark`; the search then sees it multiplied by :attr:`Exposure.target` over that
percentile, at most :attr:`Exposure.max_gain`. Daylight footage is searched as it is.

A video is measured on its first frames, and each shot again (as its bars and horizon are); a
single image, or a frame searched on its own, on itself. The frames drawn and written are never
changed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from .._settings import JsonSettings, number_in

__all__ = ["Exposure", "brighten", "exposure_gain", "picture_level"]

#: Sample every this many pixels of each axis to measure a picture's level.
_STEP = 4


@dataclass(frozen=True)
class Exposure(JsonSettings):
    """When and how much dark footage is brightened for the search.

    Parameters
    ----------
    dark : float, default 60.0
        A picture whose level (:func:`picture_level`, 0 to 255) is below this is dark, > 0.
    target : float, default 120.0
        The level a dark picture is brought to, >= ``dark``.
    max_gain : float, default 4.0
        The most a picture is multiplied by, >= 1 (the noise grows with it).

    Raises
    ------
    ValueError
        If a value is out of range; the message names the field.
    """

    dark: float = 60.0
    target: float = 120.0
    max_gain: float = 4.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "dark", number_in(self, "dark", 0.0))
        object.__setattr__(self, "target", number_in(self, "target", self.dark, low_in=True))
        object.__setattr__(self, "max_gain", number_in(self, "max_gain", 1.0, low_in=True))


def picture_level(picture: np.ndarray) -> float:
    """The 90th percentile of the luminance of the picture's lower half, 0 to 255.

    Parameters
    ----------
    picture : ndarray of uint8, shape (H, W, 3)
        An RGB picture (a frame inside its black bars).
    """
    half = np.ascontiguousarray(picture[picture.shape[0] // 2 :: _STEP, ::_STEP])
    if not half.size:
        return 255.0
    return float(np.percentile(cv2.cvtColor(half, cv2.COLOR_RGB2GRAY), 90))


def exposure_gain(level: float, rule: Exposure) -> float:
    """What a picture of ``level`` (:func:`picture_level`) is multiplied by: 1.0 unless it is dark."""
    if level >= rule.dark:
        return 1.0
    return min(rule.max_gain, rule.target / max(level, 1.0))


def brighten(frame: np.ndarray, gain: float) -> np.ndarray:
    """``frame`` multiplied by ``gain`` (rounded, saturated at 255) and smoothed so that its noise
    is not amplified: a new array; ``frame`` itself when ``gain`` is 1.

    The gain multiplies the sensor's noise too. A Gaussian blur of standard deviation
    ``gain / (2 sqrt(pi))`` pixels divides the standard deviation of white noise by ``gain``, so
    the search sees dark footage about as noisy as daylight footage.

    Parameters
    ----------
    frame : ndarray of uint8, shape (H, W, 3)
    gain : float
        >= 1.
    """
    if gain == 1.0:
        return frame
    table = np.clip(np.rint(np.arange(256) * gain), 0, 255).astype(np.uint8)
    return cv2.GaussianBlur(cv2.LUT(frame, table), (0, 0), gain / (2.0 * math.sqrt(math.pi)))
