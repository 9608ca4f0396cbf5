"""Write the notebooks in ``notebooks/`` from the cell sources below (the notebooks are generated).

    python tools/make_notebooks.py          # (re)write notebooks/*.ipynb, without outputs
    python tools/make_notebooks.py --check  # exit 1 if a committed notebook differs

Edit the cells here, not in Jupyter, so that the committed notebooks stay free of outputs and
their diffs stay readable. Cell ids are fixed (``<notebook>-<n>``), so regenerating an
unchanged notebook gives identical bytes. ``tools/regenerate.py`` executes them.

Each notebook stays thin: it calls :mod:`vehicle_detection` and draws with
:mod:`vehicle_detection.plots`, and writes every figure the writeup links to
``output_images/`` (or ``$VD_OUTPUT_DIR``) under a fixed name.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import nbformat

REPO = Path(__file__).resolve().parents[1]
NOTEBOOK_DIR = REPO / "notebooks"

SETUP = """\
%matplotlib inline
import itertools
import os
import time

import numpy as np
from IPython.display import Markdown, display

from vehicle_detection import plots

P = plots.notebook_paths()  # repo, data ($VEHICLE_DETECTION_DATA or ../data), output ($VD_OUTPUT_DIR or ../output_images)
P"""


def md(text: str) -> tuple[str, str]:
    return ("markdown", text.strip("\n"))


def code(text: str) -> tuple[str, str]:
    return ("code", text.strip("\n"))


# ------------------------------------------------------------------------------------------------
NB_DATA = [
    md("""
# 1. The training data

64x64 RGB patches of vehicles and non-vehicles (the Udacity archives: GTI, KITTI and frames of the
project video), read with `vehicle_detection.data.load_dataset`. This notebook counts them per
source folder, shows examples, finds the byte-identical duplicates and shows why a random
train/test split leaks.

Run it from `notebooks/` (Jupyter does). The data folder is `$VEHICLE_DETECTION_DATA`, else the
repository's `data/` (`vehicle-detection download` fills it); `python tools/regenerate.py`
points it at `../shared/data` when that exists.
"""),
    code(SETUP),
    code("""
from vehicle_detection.classifier import split_indices
from vehicle_detection.data import find_duplicates, load_dataset

t = time.perf_counter()
ds = load_dataset(P.data)
counts = ds.counts()
print(f"{len(ds):,} patches ({int(ds.labels.sum()):,} vehicles) loaded in {time.perf_counter() - t:.1f} s")
display(Markdown(plots.markdown_table(
    [{"folder": k, "class": "vehicle" if k.startswith("vehicles/") else "non-vehicle", "n": v} for k, v in counts.items()],
    [("folder", "source folder", ""), ("class", "class", ""), ("n", "patches", ",")],
)))
"""),
    md("""
## Duplicates

`find_duplicates` groups byte-identical files (by SHA-1 of the file bytes). The hatched part of
each bar is the files that have a twin.
"""),
    code("""
from collections import Counter

dups = find_duplicates(ds.digests)
dup_src, dup_n = np.unique(ds.sources[np.concatenate(dups)], return_counts=True)
kinds = Counter(" + ".join(sorted(set(ds.sources[g]))) for g in dups)
print(f"{len(dups)} groups of identical files, {sum(map(len, dups))} files")
display(Markdown(plots.markdown_table([{"k": k, "n": n} for k, n in kinds.items()], [("k", "folders of the group", ""), ("n", "groups", "")])))
fig = plots.counts_figure(counts, duplicates=dict(zip(dup_src, dup_n)))
plots.save_figure(fig, P.output / "dataset_counts.png")
"""),
    code("""
by_kind = {}
for g in dups:
    by_kind.setdefault(" + ".join(sorted(set(ds.sources[g]))), []).append(g)
shown = [g for groups in by_kind.values() for g in groups[:3]][:8]
names = [n.rsplit("/", 1)[-1] for n in ds.names]
fig = plots.image_grid(
    [ds.images[g[0]] for g in shown] + [ds.images[g[1]] for g in shown], ncols=len(shown),
    titles=[f"{ds.sources[g[k]].split('/')[1]}\\n{names[g[k]]}" for k in (0, 1) for g in shown],
    suptitle="Byte-identical pairs: first file (top) and its twin (bottom)", cell=1.2, fontsize=6,
)
plots.save_figure(fig, P.output / "dataset_duplicates.png")
"""),
    md("""
## Examples

Eight random patches from each source folder. KITTI crops are blurrier and differently lit
than the GTI ones; `non-vehicles/Extras` are crops of the project video itself (road, rails,
trees, lane lines).
"""),
    code("""
rng = np.random.default_rng(0)
picks = np.concatenate([rng.choice(np.flatnonzero(ds.sources == s), 8, replace=False) for s in counts])
fig = plots.image_grid(ds.images[picks], ncols=8, row_labels=list(counts), suptitle="Random patches per source folder", cell=1.0)
plots.save_figure(fig, P.output / "dataset_examples.png")
"""),
    md("""
## Time series and leakage

The GTI folders are sequences: consecutive file numbers are the same car a few frames apart.
`load_dataset` puts each run of `track_length=100` consecutive file numbers of a folder into
one group (merged with the groups of byte-identical files), and a grouped split
(`split_indices(labels, groups)`) keeps every group on one side.
"""),
    code("""
start = np.flatnonzero(ds.sources == "vehicles/GTI_Right")[40]
run = np.arange(start, start + 16)
fig = plots.image_grid(ds.images[run], ncols=8, titles=[f"{names[i]}, group {ds.groups[i]}" for i in run],
                       suptitle="16 consecutive GTI_Right files, all in one group: runs of near copies of the same car", cell=1.2, fontsize=6)
plots.save_figure(fig, P.output / "dataset_gti_sequence.png")
"""),
    code("""
rows = []
for name, groups in (("random", None), ("grouped", ds.groups)):
    tr, te = split_indices(ds.labels, groups, test_size=0.2, random_state=0)
    rows.append({
        "split": name, "train": len(tr), "test": len(te),
        "twin": int(np.isin(ds.digests[te], ds.digests[tr]).sum()),
        "group": float(np.isin(ds.groups[te], ds.groups[tr]).mean()),
    })
print(f"{len(np.unique(ds.groups)):,} groups")
display(Markdown(plots.markdown_table(rows, [
    ("split", "80/20 split", ""), ("train", "train", ","), ("test", "test", ","),
    ("twin", "test patches with a byte-identical twin in train", ""),
    ("group", "test patches whose group is also in train", ".1%"),
])))
"""),
    md("""
In the random split practically every test patch has other members of its group (its
sequence block) in the training set, and dozens have an exact twin there, so its accuracy
partly measures recall of near copies. The grouped split has no
shared group and no shared file: its accuracy is the honest one (notebook 3).
"""),
]

# ------------------------------------------------------------------------------------------------
NB_FEATURES = [
    md("""
# 2. Features

The embedded model's `FeatureConfig` fixes the features: colour space, spatial bins, colour
histograms and HOG (`vehicle_detection.features`). This notebook draws each part for one
vehicle and one non-vehicle patch, and the whole vector before and after standardisation.
"""),
    code(SETUP),
    code("""
from vehicle_detection.classifier import load_default_model
from vehicle_detection.data import load_dataset
from vehicle_detection.features import COLOR_SPACES, FeatureConfig, extract_features

model = load_default_model()
cfg = model.config
print(cfg)
ds = load_dataset(P.data)
patches = {
    "vehicle": ds.images[np.flatnonzero(ds.sources == "vehicles/KITTI_extracted")[1116]],
    "non-vehicle": ds.images[np.flatnonzero(ds.sources == "non-vehicles/Extras")[1264]],
}
"""),
    md("""
## Colour spaces

Every channel of the two patches in the six colour spaces `convert_color` supports. Luma
channels (Y of YUV/YCrCb, L of LUV/HLS, V of HSV) carry the shape; the chroma channels of
YCrCb/YUV/LUV separate saturated car paint from the grey road.
"""),
    code("""
fig = plots.color_space_figure(patches, COLOR_SPACES)
plots.save_figure(fig, P.output / "color_spaces.png")
"""),
    md("""
## HOG per channel

`features.hog_image` draws scikit-image's HOG picture (unsigned; a signed configuration is drawn
with half as many bins). The model uses all three YCrCb channels: the luma HOG carries the car's
outline, the chroma HOGs its coloured panels and tail lights.
"""),
    code("""
fig = plots.hog_figure(patches, cfg)
plots.save_figure(fig, P.output / "hog_per_channel.png")
"""),
    md("""
## HOG parameters

The same Y channel with different orientations and cell sizes. 4-pixel cells resolve noise and
give a vector four times longer; 16-pixel cells blur the car into a few blobs. 8-pixel cells and
2x2 blocks keep the rear window, lights and bumper as separate cells. The sweep in notebook 3 is
the evidence behind the choice.
"""),
    code("""
variants = [
    FeatureConfig(orientations=9, signed=False, hog_sqrt=False, pixels_per_cell=4),
    FeatureConfig(orientations=9, signed=False, hog_sqrt=False, pixels_per_cell=8),
    FeatureConfig(orientations=9, signed=False, hog_sqrt=False, pixels_per_cell=16),
    cfg,
]
fig = plots.hog_parameters_figure(patches["vehicle"], variants, title="HOG of the Y channel of the vehicle patch (last: the model's configuration)")
plots.save_figure(fig, P.output / "hog_parameters.png")
"""),
    md("""
## Spatial bins and colour histograms

Spatial bins are the patch shrunk to `spatial_size x spatial_size` (block means), colour
histograms count the pixels of each channel in `hist_bins` bins. Both are computed in the
model's colour space.
"""),
    code("""
fig = plots.spatial_bins_figure(patches, cfg)
plots.save_figure(fig, P.output / "spatial_bins.png")
"""),
    code("""
fig = plots.histogram_figure(patches, cfg)
plots.save_figure(fig, P.output / "color_histograms.png")
"""),
    md("""
## The feature vector, before and after scaling

`extract_features` concatenates `[spatial | histograms | HOG]`. The raw parts differ by orders
of magnitude (pixel means up to 255, histogram counts up to 4096, HOG values below 1), so the
model standardises each feature with the training set's mean and standard deviation (stored in
the model as `scaler_mean` and `scaler_scale`) before the linear SVM.
"""),
    code("""
raw = extract_features(patches["vehicle"], cfg)
scaled = (raw - model.scaler_mean) / model.scaler_scale
display(Markdown(plots.markdown_table(
    [{"part": k, "n": s.stop - s.start, "lo": float(raw[s].min()), "hi": float(raw[s].max()),
      "zlo": float(scaled[s].min()), "zhi": float(scaled[s].max())} for k, s in cfg.layout().items()],
    [("part", "part", ""), ("n", "length", ","), ("lo", "raw min", ".3g"), ("hi", "raw max", ".3g"),
     ("zlo", "scaled min", ".2f"), ("zhi", "scaled max", ".2f")],
)))
fig = plots.feature_vector_figure(raw, scaled, cfg.layout(), title=f"Feature vector of the vehicle patch ({cfg.n_features:,} values)")
plots.save_figure(fig, P.output / "feature_vector_scaling.png")
"""),
]

# ------------------------------------------------------------------------------------------------
NB_CLASSIFIER = [
    md("""
# 3. Classifier

A `StandardScaler` and a linear SVM (`vehicle_detection.classifier`). The embedded model was
trained with `vehicle-detection train` on all 17,760 patches; its `metrics` hold the scores
of two held-out 80/20 evaluations run before the final fit: a random split and a grouped split
(no GTI sequence block and no duplicate file on both sides, see notebook 1). This notebook does
not retrain the final model.
"""),
    code(SETUP),
    code("""
from vehicle_detection.classifier import DEFAULT_C, VehicleClassifier, load_default_model, split_indices, sweep
from vehicle_detection.data import load_dataset
from vehicle_detection.features import extract_features

model = load_default_model()
m = model.metrics
display(Markdown(plots.markdown_table(
    [dict(split=k.replace("_", " "), **m[k]) for k in ("random_split", "grouped_split")],
    [("split", "split", ""), ("n_train", "train", ","), ("n_test", "test", ","), ("accuracy", "accuracy", ".4f"),
     ("precision", "precision", ".4f"), ("recall", "recall", ".4f")],
)))
print(f"{m['n_features']:,} features, C = {m['C']}, final fit on {m['n_images']:,} patches")
fig = plots.accuracy_figure(m)
plots.save_figure(fig, P.output / "classifier_accuracy_splits.png")
"""),
    md("""
## Parameter sweep (quick version)

`classifier.sweep` scores feature configurations on both splits. Here: a stratified subsample
of 3,000 patches and eight configurations (`plots.showcase_configs`), about half a minute.
With 600 test patches one mistake is 0.17 points, so differences below about 0.5 points are
noise: this table shows the method, not the verdict. The same eight configurations on all
17,760 patches (a few minutes) are

    python tools/sweep_features.py --data-dir ../shared/data

and the command line sweeps the classic grid (colour spaces x orientations x cell sizes x
colour features, unsigned HOG):

    vehicle-detection sweep --data-dir ../shared/data
"""),
    code("""
ds = load_dataset(P.data)
_, keep = split_indices(ds.labels, test_size=3000 / len(ds), random_state=0)
sub = ds.subset(np.sort(keep))
configs = plots.showcase_configs(model.config)  # classic choices, signed HOG, the model's
t = time.perf_counter()
rows = sweep(sub, configs, C=DEFAULT_C, n_jobs=2)
print(f"{len(configs)} configurations on {len(sub):,} patches in {time.perf_counter() - t:.0f} s")
for r in rows:
    r["name"] = plots.sweep_label(r)
display(Markdown(plots.markdown_table(rows, [
    ("name", "configuration", ""), ("n_features", "features", ","), ("random_accuracy", "random split", ".4f"),
    ("grouped_accuracy", "grouped split", ".4f"), ("feature_seconds", "feature s", ".2f"),
])))
fig = plots.sweep_figure(rows, n_images=len(sub))
plots.save_figure(fig, P.output / "classifier_sweep.png")
"""),
    md("""
## Confusion matrix and hardest mistakes

The embedded model saw every patch, so its own mistakes cannot be measured on the training
set. Instead this refits the model's configuration on the **train side of the grouped split of
all patches** (same seed, test size and C as the stored metrics) and scores its **test side**:
the same evaluation as `metrics['grouped_split']`, redone here (about 15 s).
"""),
    code("""
cfg = model.config
t = time.perf_counter()
X = extract_features(ds.images, cfg)
tr, te = split_indices(ds.labels, ds.groups, test_size=m["test_size"], random_state=m["random_state"])
held_out = VehicleClassifier.fit(X[tr], ds.labels[tr], cfg, C=m["C"])
margin = held_out.decision_function(X[te])
y, pred = ds.labels[te], (margin > 0).astype(int)
confusion = {"tn": int(((pred == 0) & (y == 0)).sum()), "fp": int(((pred == 1) & (y == 0)).sum()),
             "fn": int(((pred == 0) & (y == 1)).sum()), "tp": int(((pred == 1) & (y == 1)).sum())}
print(f"{time.perf_counter() - t:.0f} s; accuracy {np.mean(pred == y):.4f} on {len(te):,} held-out patches")
print("this run:      ", confusion)
print("stored metrics:", m["grouped_split"]["confusion"])
fig = plots.confusion_figure(confusion, title=f"Grouped split, test side ({len(te):,} patches)")
plots.save_figure(fig, P.output / "classifier_confusion_matrix.png")
"""),
    md("""
The hardest mistakes: the non-vehicles with the largest positive margin (false positives) and
the vehicles with the most negative margin (missed), with their source folder.
"""),
    code("""
false_pos = te[(pred == 1) & (y == 0)][np.argsort(-margin[(pred == 1) & (y == 0)])][:8]
missed = te[(pred == 0) & (y == 1)][np.argsort(margin[(pred == 0) & (y == 1)])][:8]
margin_of = dict(zip(te, margin))
pad = lambda idx: list(idx) + [None] * (8 - len(idx))
order = pad(false_pos) + pad(missed)
fig = plots.image_grid(
    [None if i is None else ds.images[i] for i in order], ncols=8,
    titles=["" if i is None else f"{ds.sources[i].split('/')[1]}\\n{margin_of[i]:+.2f}" for i in order],
    row_labels=["false\\npositives", "missed\\nvehicles"], cell=1.15, fontsize=6,
    suptitle="Hardest held-out mistakes (grouped split), SVM margin under each",
)
plots.save_figure(fig, P.output / "classifier_hardest_mistakes.png")
"""),
]

# ------------------------------------------------------------------------------------------------
NB_WINDOWS = [
    md("""
# 4. Sliding-window search on the test images

`Detector()` with its defaults: the embedded model, the default `SearchPlan` (four window
sizes in bands of the road) and heat-map settings. `Detector.detect_image` runs the fast
search (`search.search`, every window scored at once), adds each hot window's margin to a
heat map, thresholds it, labels the blobs (`heatmap.label_heat`) and boxes the plausible ones
(`heatmap.heat_to_boxes`).
"""),
    code(SETUP),
    code("""
from vehicle_detection.detector import Detector
from vehicle_detection.images import read_image
from vehicle_detection.search import plan_windows

det = Detector()
cfg, plan = det.model.config, det.plan
frames = {p.stem: read_image(p) for p in sorted((P.repo / "test_images").glob("test*.jpg"))}
grids = plan_windows(frames["test1"].shape, plan, cfg)
display(Markdown(plots.markdown_table(
    [{"scale": s.scale, "px": cfg.window * s.scale, "rows": f"{s.y_start}-{s.y_stop}",
      "step": s.step * cfg.pixels_per_cell * s.scale, "overlap": 1 - s.step * cfg.pixels_per_cell / cfg.window,
      "n": len(b)} for s, b in zip(plan.scales, grids)],
    [("scale", "scale", "g"), ("px", "window (px)", ".0f"), ("rows", "rows searched", ""), ("step", "step (px)", ".0f"),
     ("overlap", "overlap", ".1%"), ("n", "windows", ",")],
)))
print(f"{sum(map(len, grids)):,} windows per frame; a window is hot when its margin > {plan.threshold}")
"""),
    code("""
fig = plots.window_grid_figure(frames["test1"], plan, cfg, rows=(300, 720))
plots.save_figure(fig, P.output / "sliding_window_grid.png")
"""),
    md("""
## Windows, heat, labels, boxes

For each test image: the hot windows (colour = window size), the heat map (each hot window adds
its margin above the threshold), the blobs of heat above `Detector.image_threshold`, and one
box per blob that passes the size and aspect filters (`TrackerConfig.min_size`,
`aspect_range`). A single image has no temporal filter; the video notebook adds it.
"""),
    code("""
det.detect_image(frames["test1"])  # compile the kernels outside the timing
t = time.perf_counter()
results = {name: det.detect_image(frame) for name, frame in frames.items()}
print(f"{len(frames) / (time.perf_counter() - t):.1f} images per second")
display(Markdown(plots.markdown_table(
    [{"name": k, "w": len(r.windows), "b": len(r.boxes), "peak": ", ".join(f"{s:.1f}" for s in r.scores)} for k, r in results.items()],
    [("name", "image", ""), ("w", "hot windows", ""), ("b", "boxes", ""), ("peak", "peak heat per box", "")],
)))
fig = plots.detection_stages_figure([(k, frames[k], r) for k, r in results.items()], det, rows=(340, 720))
plots.save_figure(fig, P.output / "heatmaps_test_images.png")
"""),
    code("""
fig = plots.boxes_grid_figure([(k, frames[k], r.boxes) for k, r in results.items()], title="Final boxes on the six test images (Detector.detect_image)")
plots.save_figure(fig, P.output / "final_boxes_test_images.png")
"""),
]

# ------------------------------------------------------------------------------------------------
NB_VIDEO = [
    md("""
# 5. Video: heat over frames, tracks, processed videos, scores

`process_video` decodes a video, runs the detector on every frame (search, then
`tracker.Tracker.update`: heat integrated over frames, hot blobs matched to tracks, a track
reported after `min_hits` frames) and writes the annotated MP4. Set `VD_MAX_FRAMES` to process
only the first frames of the project clip (the notebook test does).
"""),
    code(SETUP),
    code("""
from vehicle_detection.detector import Detector
from vehicle_detection.evaluate import Annotations, evaluate_detections, load_annotations
from vehicle_detection.pipeline import process_video
from vehicle_detection.video import probe_video, read_frames

MAX_FRAMES = int(os.environ.get("VD_MAX_FRAMES", 0)) or None  # None: whole videos
TEST_VIDEO = P.repo / "test_video.mp4"
CLIP = P.data / "videos" / "project_video_clip_A.mp4"
LABELS = P.data / "annotations" / "project_video_clip_A.json"
det = Detector()
print(det.tracker)
"""),
    md("""
## Frame by frame

The first six frames of `test_video.mp4`: the hot windows of each frame, the integrated heat
(`integrated = decay * integrated + current`) with the threshold contour, and the confirmed
tracks. Windows appear from the first frame, but a track is reported only once its blob has been
matched in `min_hits` frames: a one-frame false positive never is.
"""),
    code("""
records = plots.track_frames(det, read_frames(TEST_VIDEO), first=0, count=6)
fig = plots.frame_sequence_figure(records, det, rows=(340, 720))
plots.save_figure(fig, P.output / "video_frames_heat_tracks.png")
"""),
    md("""
The same view for frames 20-25 of project clip A, with a black and a white car side by side:
whether their heat forms one blob or two, and how much of a blob is kept as its core
(`TrackerConfig.peak_fraction`), decides whether both cars are reported. Faint heat left of
them is the decayed trace of windows from earlier frames.
"""),
    code("""
records = plots.track_frames(det, read_frames(CLIP), first=20, count=6)
fig = plots.frame_sequence_figure(records, det, rows=(340, 720))
plots.save_figure(fig, P.output / "video_frames_clip_A.png")
"""),
    md("""
## The processed videos
"""),
    code("""
runs = {
    "test video": (TEST_VIDEO, P.output / "test_video_detected.mp4", None),
    "project clip A": (CLIP, P.output / "project_clip_A_detected.mp4", MAX_FRAMES),
}
videos = {}
for name, (src, out, limit) in runs.items():
    t = time.perf_counter()
    # veryfast keeps the committed videos small; the command line defaults to ultrafast (speed)
    table = process_video(src, out, detector=det, overwrite=True, progress=False, max_frames=limit, preset="veryfast")
    seconds = time.perf_counter() - t
    n = min(limit or np.inf, probe_video(src).n_frames)
    videos[name] = (table, n)
    print(f"{name}: {n} frames in {seconds:.1f} s ({n / seconds:.1f} frames/s, decode + detect + encode), {len(table)} boxes, "
          f"track ids {sorted(set(table.track_id.tolist()))} -> {out.name} ({out.stat().st_size / 1e6:.1f} MB)")
"""),
    code("""
table, n = videos["project clip A"]
fig = plots.tracks_timeline_figure(table, n, title="Project clip A: reported tracks per frame")
plots.save_figure(fig, P.output / "video_tracks_timeline.png")
"""),
    md("""
## Scores on the labelled frames

Frames 0, 50, ..., 250 of clip A are hand-labelled (`annotations/project_video_clip_A.json`:
cars that must be found and ignore regions for far or oncoming traffic).
`evaluate.evaluate_detections` matches the reported boxes one to one at IoU >= 0.5 (and
0.3). The command line gives the same numbers:

    vehicle-detection evaluate --video ../shared/data/videos/project_video_clip_A.mp4 \\
        --labels ../shared/data/annotations/project_video_clip_A.json
"""),
    code("""
labels = load_annotations(LABELS)
scored = Annotations(labels.video, {i: f for i, f in labels.frames.items() if i < n})  # frames processed
scores = evaluate_detections(table.by_frame(), scored, iou_thresholds=(0.5, 0.3))
display(Markdown(plots.markdown_table(
    [dict(iou=t, **s.as_dict()) for t, s in scores.items()],
    [("iou", "IoU >=", "g"), ("n_frames", "frames", ""), ("tp", "TP", ""), ("fp", "FP", ""), ("fn", "FN", ""),
     ("ignored", "ignored", ""), ("precision", "precision", ".3f"), ("recall", "recall", ".3f"), ("f1", "F1", ".3f")],
)))
labelled = {i: f for i, f in enumerate(itertools.islice(read_frames(CLIP), n)) if i in scored.frames}
fig = plots.labelled_frames_figure(labelled, scored, table.by_frame())
plots.save_figure(fig, P.output / "evaluation_labelled_frames.png")
"""),
]

NOTEBOOKS = {
    "01_data.ipynb": NB_DATA,
    "02_features.ipynb": NB_FEATURES,
    "03_classifier.ipynb": NB_CLASSIFIER,
    "04_sliding_windows.ipynb": NB_WINDOWS,
    "05_video.ipynb": NB_VIDEO,
}


def build(name: str, cells) -> nbformat.NotebookNode:
    nb = nbformat.v4.new_notebook()
    nb.metadata = {
        "kernelspec": {"display_name": "Python 3", "language": "python", "name": "python3"},
        "language_info": {"name": "python"},
    }
    stem = name.split(".")[0]
    for i, (kind, src) in enumerate(cells):
        cell = nbformat.v4.new_markdown_cell(src) if kind == "markdown" else nbformat.v4.new_code_cell(src)
        cell.id = f"{stem}-{i}"
        nb.cells.append(cell)
    nbformat.validate(nb)
    return nb


def render(name: str) -> str:
    return nbformat.writes(build(name, NOTEBOOKS[name])) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--check", action="store_true", help="only compare; exit 1 if a notebook differs")
    args = ap.parse_args(argv)
    stale = []
    for name in NOTEBOOKS:
        path = NOTEBOOK_DIR / name
        text = render(name)
        if path.is_file() and path.read_text(encoding="utf-8") == text:
            continue
        stale.append(name)
        if not args.check:
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(text, encoding="utf-8")
            print(f"wrote {path.relative_to(REPO)}")
    if args.check and stale:
        print(f"out of date (run python tools/make_notebooks.py): {', '.join(stale)}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
