# The names of vehicle_detection.viz, loaded on first use (lazy_loader.attach_stub reads this file).
from . import plots
from .drawing import add_caption, draw_boxes, draw_caption, draw_detections, failure_sheet, failure_tile, place_labels, tile_view
from .report import RunSummary, summarize, write_html_report
