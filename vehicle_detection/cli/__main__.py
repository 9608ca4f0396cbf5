"""``python -m vehicle_detection.cli``: the command line."""

from .main import run

run()
