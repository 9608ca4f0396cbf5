# The names of vehicle_detection.road, loaded on first use (lazy_loader.attach_stub reads this file).
from .autocamera import EstimateSettings, RoadEstimate, estimate_birds_eye, road_transform, save_estimate
from .camera import Camera, calibrate, find_chessboard
from .distance import DistanceFilter, DistanceTracker, smooth_distances
from .lanes import (
    BirdsEye,
    Lane,
    LaneTracker,
    birds_eye_from_straight,
    draw_lane,
    find_lane_pixels,
    fit_lanes,
    fit_parallel_lanes,
    lane_binary,
    lane_measures,
    lane_row,
    lane_sane,
    search_around,
    vertical_paint,
)
from .survey import Road, RoadSurvey
