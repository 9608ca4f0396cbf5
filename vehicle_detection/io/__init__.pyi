# The names of vehicle_detection.io, loaded on first use (lazy_loader.attach_stub reads this file).
from ._files import (
    PARTIAL_SUFFIX,
    atomic_output,
    check_output_path,
    check_outputs,
    input_file,
    interrupt_on_signals,
    output_batch,
    read_text,
    refuse_inputs,
    umask,
)
from .formats import FORMATS, read_parquet, write_coco, write_mot, write_parquet, write_tables
from .images import (
    IMAGE_EXTENSIONS,
    as_image,
    as_rgb_uint8,
    check_frame_shape,
    check_image_output,
    decode_image,
    list_images,
    read_image,
    write_image,
)
from .progress import in_notebook, plural, progress_bar
from .tables import read_boxes_csv, read_lanes_csv, write_boxes_csv, write_lanes_csv
from .timeline import Timeline
from .video import VIDEO_SUFFIXES, X264_PRESETS, Encoding, VideoInfo, VideoWriter, check_video_output, probe_video, read_frames
