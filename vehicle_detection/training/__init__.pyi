# The names of vehicle_detection.training, loaded on first use (lazy_loader.attach_stub reads this file).
from .augment import AugmentConfig
from .data import Dataset, check_split_sizes, default_data_dir, find_duplicates, list_extra_negatives, load_dataset
from .download import download_archives
from .fit import split_indices, with_copies, sweep, sweep_configs, train, with_box_refinement
from .mining import MinedNegatives, MiningOptions, MiningSource, labelled_dataset, labelled_frames, mine_negatives, write_negatives
