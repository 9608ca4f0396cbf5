# The names of vehicle_detection.pipeline, loaded on first use (lazy_loader.attach_stub reads this file).
from .batch import detect_chunked, detect_many, join_chunks, track_chunk
from .inputs import (
    InputOptions,
    InputResult,
    Outputs,
    default_outputs,
    expand_inputs,
    input_kind,
    run_input,
)
from .live import MoviepyAdapter
from .video import frame_range, process_video
