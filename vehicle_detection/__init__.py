"""vehicle-detection: find and track vehicles in dashcam video with HOG features and a linear SVM.

The public API is loaded lazily: ``import vehicle_detection as vd`` is fast, and each name
imports its module on first use.

>>> import vehicle_detection as vd
>>> detector = vd.Detector()                                    # the embedded model
>>> found = detector.detect_image(vd.read_image("test_images/test1.jpg"))
>>> type(found).__name__, found.xyxy.shape[1]
('Detections', 4)
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

__version__ = "0.2.0"

# Public name -> module that defines it. No public name may equal a module's name: importing the
# module (which the package itself does) would rebind the package attribute to the module.
_API = {
    # results and geometry
    "Detections": "detections",
    "box_iou": "geometry",
    "match_boxes": "geometry",
    # the pipeline
    "Detector": "detector",
    "DetectorConfig": "config",
    "FeatureConfig": "features",
    "extract_features": "features",
    "SearchPlan": "search",
    "SearchScale": "search",
    "estimate_horizon": "horizon",
    "vanishing_row": "horizon",
    "active_area": "overlays",
    "static_mask": "overlays",
    "find_overlays": "overlays",
    "Tracker": "tracker",
    "TrackerConfig": "tracker",
    "process_video": "pipeline",
    "detect_many": "batch",
    "InputResult": "batch",
    "MoviepyAdapter": "live",
    # camera, lanes and distances
    "Camera": "camera",
    "calibrate": "camera",
    "BirdsEye": "lanes",
    "birds_eye_from_straight": "lanes",
    "lane_binary": "lanes",
    "find_lane_pixels": "lanes",
    "fit_lanes": "lanes",
    "Lane": "lanes",
    "LaneTracker": "lanes",
    "DistanceTracker": "lanes",
    "draw_lane": "lanes",
    # models and training
    "VehicleClassifier": "classifier",
    "load_model": "classifier",
    "load_default_model": "classifier",
    "train": "classifier",
    "sweep": "classifier",
    "sweep_configs": "classifier",
    "split_indices": "classifier",
    "load_dataset": "data",
    "find_duplicates": "data",
    "MiningSource": "mining",
    "mine_negatives": "mining",
    "write_negatives": "mining",
    # images, video, tables, drawing
    "read_image": "images",
    "write_image": "images",
    "list_images": "images",
    "read_frames": "video",
    "probe_video": "video",
    "VideoWriter": "video",
    "read_boxes_csv": "tables",
    "write_boxes_csv": "tables",
    "write_mot": "formats",
    "write_coco": "formats",
    "write_parquet": "formats",
    "read_parquet": "formats",
    "write_lanes_csv": "tables",
    "draw_boxes": "drawing",
    "draw_detections": "drawing",
    # evaluation
    "Annotations": "evaluate",
    "FrameLabels": "evaluate",
    "load_annotations": "evaluate",
    "evaluate_detections": "evaluate",
    "evaluation_report": "evaluate",
    "average_precision": "evaluate",
    "match_frame": "evaluate",
    "tracking_scores": "tracking_metrics",
}

__all__ = ["__version__", *_API]


def __getattr__(name: str):
    module = _API.get(name)
    if module is None:
        raise AttributeError(f"module 'vehicle_detection' has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{module}", __name__), name)
    globals()[name] = value  # later look-ups skip this function
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_API))


if TYPE_CHECKING:  # for type checkers and IDEs; nothing is imported at run time
    from .road.camera import Camera, calibrate
    from .road.lanes import BirdsEye, DistanceTracker, Lane, LaneTracker, birds_eye_from_straight, draw_lane, find_lane_pixels, fit_lanes, lane_binary
    from .classifier import VehicleClassifier, load_default_model, load_model, split_indices, sweep, sweep_configs, train
    from .config import DetectorConfig
    from .training.data import find_duplicates, load_dataset
    from .detections import Detections
    from .detector import Detector
    from .viz.drawing import draw_boxes, draw_detections
    from .metrics.detection import Annotations, FrameLabels, average_precision, evaluate_detections, evaluation_report, load_annotations, match_frame
    from .features import FeatureConfig, extract_features
    from .geometry import box_iou, match_boxes
    from .io.images import list_images, read_image, write_image
    from .training.mining import MiningSource, mine_negatives, write_negatives
    from .search import SearchPlan, SearchScale
    from .horizon import estimate_horizon, vanishing_row
    from .overlays import active_area, find_overlays, static_mask
    from .tracker import Tracker, TrackerConfig
    from .io.tables import read_boxes_csv, write_boxes_csv, write_lanes_csv
    from .metrics.tracking import tracking_scores
    from .pipeline.video import process_video
    from .pipeline.batch import InputResult, detect_many
    from .io.formats import read_parquet, write_coco, write_mot, write_parquet
    from .pipeline.live import MoviepyAdapter
    from .io.video import VideoWriter, probe_video, read_frames
