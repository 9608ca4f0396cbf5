# The names of vehicle_detection.metrics, loaded on first use (lazy_loader.attach_stub reads this file).
from .detection import (
    Annotations,
    Failure,
    FrameLabels,
    FrameMatch,
    Scores,
    average_precision,
    camera_name,
    evaluate_detections,
    evaluation_report,
    find_failures,
    load_annotations,
    match_frame,
    pool_by_camera,
    pool_reports,
)
from .reporting import ReportSource, write_evaluation_report
from .runner import detect_labelled, evaluate_labelled
from .tracking import TrackingScores, tracking_scores
