# The public API of vehicle_detection, loaded on first use (lazy_loader.attach_stub reads this file).
# The subpackages, each with a stub of its own names:
from . import footage, io, metrics, pipeline, road, training, viz

# Results and geometry (the base)
from .detections import Detections
from .geometry import box_iou, match_boxes

# The core: features, classifier, search, heat, tracker, and the detector that runs them
from .classifier import VehicleClassifier, load_default_model, load_model
from .config import DetectorConfig
from .detector import Detector
from .features import FeatureConfig, extract_features
from .refine import SideFit, fit_sides
from .search import SearchPlan, SearchScale
from .tracker import Tracker, TrackerConfig

# The footage: its horizon, exposure, cuts between shots, bars and overlays
from .footage.exposure import Exposure
from .footage.horizon import CarHorizon, estimate_horizon, horizon_from_cars, vanishing_row
from .footage.overlays import active_area, find_overlays, static_mask
from .footage.shots import ShotCuts

# Images, video, tables and their formats
from .io.formats import read_parquet, write_coco, write_mot, write_parquet
from .io.images import list_images, read_image, write_image
from .io.tables import read_boxes_csv, read_lanes_csv, write_boxes_csv, write_lanes_csv
from .io.video import Encoding, VideoWriter, probe_video, read_frames
from .io.timeline import Timeline

# Camera, lanes and distances
from .road.camera import Camera, calibrate
from .road.distance import DistanceTracker
from .road.lanes import BirdsEye, Lane, LaneTracker, birds_eye_from_straight, draw_lane, find_lane_pixels, fit_lanes, lane_binary
from .road.survey import Road

# Evaluation
from .metrics.detection import (
    Annotations,
    FrameLabels,
    average_precision,
    evaluate_detections,
    evaluation_report,
    load_annotations,
    match_frame,
)
from .metrics.tracking import tracking_scores

# Training
from .training.augment import AugmentConfig
from .training.data import find_duplicates, load_dataset
from .training.fit import split_indices, sweep, sweep_configs, train
from .training.mining import MiningOptions, MiningSource, mine_negatives, write_negatives

# Drawing
from .viz.drawing import draw_boxes, draw_detections
from .viz.report import RunSummary, summarize, write_html_report

# Whole runs
from .pipeline.batch import detect_many
from .pipeline.inputs import InputOptions, InputResult, run_input
from .pipeline.live import MoviepyAdapter
from .pipeline.video import process_video
