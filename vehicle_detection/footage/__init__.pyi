# The names of vehicle_detection.footage, loaded on first use (lazy_loader.attach_stub reads this file).
from .exposure import Exposure, brighten, exposure_gain, picture_level
from .horizon import TOLERANCE, CarHorizon, estimate_horizon, horizon_from_cars, implied_horizon, vanishing_row
from .overlays import BarParams, MaskParams, Overlays, active_area, find_overlays, mask_integral, mask_share, static_mask
from .shots import THUMBNAIL, ShotCuts, frame_change, next_shot, thumbnail
