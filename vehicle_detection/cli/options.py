"""What several commands share: the options they read into the library's objects."""

from __future__ import annotations

import dataclasses
import functools
import sys

from ..detector import Detector
from ..errors import UsageError
from ..features import FeatureConfig
from ..road.camera import Camera

__all__ = ["feature_config", "load_detector", "load_camera", "csv_ints", "human_print"]


def feature_config(args) -> FeatureConfig:
    """The :class:`FeatureConfig` of ``train``'s feature options."""
    try:
        channels = tuple(int(c) for c in str(args.hog_channels).split(",") if c.strip())
        return FeatureConfig(
            color_space=args.color_space,
            hog_channels=channels,
            orientations=args.orientations,
            pixels_per_cell=args.pixels_per_cell,
            cells_per_block=args.cells_per_block,
            signed=bool(args.signed),
            hog_sqrt=bool(args.hog_sqrt),
            spatial_size=args.spatial_size,
            hist_bins=args.hist_bins,
        )
    except ValueError as exc:  # an option value that cannot work: a bad command line
        raise UsageError(str(exc)) from None


def load_camera(path) -> Camera | None:
    """``--camera``: the camera file, or None."""
    return None if path is None else Camera.load(path)


def load_detector(model_path, horizon: float | str | None = None, full_search_every: int | None = None,
                  traffic: str | None = None) -> Detector:
    """``--model``, ``--horizon``, ``--full-search-every`` and ``--traffic``: the detector."""
    detector = Detector.load(model_path or None, horizon=horizon, traffic=traffic)
    if full_search_every is None:
        return detector
    config = detector.config
    return Detector(detector.model, config.replace(plan=dataclasses.replace(config.plan, full_search_every=full_search_every)))


def csv_ints(text: str, what: str) -> list[int]:
    """``--what 1,2,3`` as whole numbers."""
    try:
        return [int(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise UsageError(f"--{what}: expected comma-separated integers, got {text!r}") from None


def human_print(args):
    """``print`` for a command's human lines: to stderr with ``--json`` (stdout then holds the JSON object alone)."""
    return functools.partial(print, file=sys.stderr) if getattr(args, "json", False) else print
