"""Figures for the notebooks and the writeup: contact sheets, HOG pictures, search grids, heat maps.

Every ``*_figure`` function takes data the rest of the package produces and returns a
:class:`matplotlib.figure.Figure` (made with :mod:`matplotlib.pyplot`, so a notebook shows it
inline); :func:`save_figure` writes it as a small PNG. Nothing here changes how vehicles are
detected: these are views of the package's results.

Paths for notebooks (:func:`notebook_paths`): a notebook runs with its own folder
(``notebooks/``) as the working directory; the repository is its parent. The training data are
found as the tests find them: ``$VEHICLE_DETECTION_DATA`` when set, else ``../shared/data``
beside the checkout when it exists, else the repository's ``data/``; figures go to
``$VD_OUTPUT_DIR``, else to the repository's ``output_images/``.
"""

from __future__ import annotations

import io
import itertools
import os
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image

from ..errors import require
from ..features import COLOR_SPACES, FeatureConfig, bin_spatial, color_histogram, convert_color, hog_image
from ..geometry import box_iou
from ..heatmap import label_heat
from ..metrics.detection import match_frame
from ..search import plan_windows
from ..training.data import DATA_ENV, default_data_dir
from ..io import plural

# matplotlib is not part of the command-line install: importing this module says which extra has it.
plt = require("matplotlib.pyplot", "notebooks", "the figures (vehicle_detection.viz.plots)")
from matplotlib.colors import ListedColormap, PowerNorm, to_rgb  # noqa: E402
from matplotlib.patches import Rectangle  # noqa: E402

__all__ = [
    "OUTPUT_ENV",
    "NotebookPaths",
    "notebook_paths",
    "save_figure",
    "markdown_table",
    "image_grid",
    "counts_figure",
    "color_space_figure",
    "hog_figure",
    "hog_parameters_figure",
    "spatial_bins_figure",
    "histogram_figure",
    "feature_vector_figure",
    "accuracy_figure",
    "sweep_figure",
    "confusion_figure",
    "search_plan_table",
    "window_grid_figure",
    "detection_stages_figure",
    "boxes_grid_figure",
    "track_frames",
    "frame_sequence_figure",
    "tracks_timeline_figure",
    "labelled_frames_figure",
    "showcase_configs",
    "sweep_label",
]

#: Environment variable naming the folder figures are written to.
OUTPUT_ENV = "VD_OUTPUT_DIR"
#: PNGs above this size are re-encoded with a 256-colour palette (photographs; most plots stay below).
PNG_BUDGET = 100_000

# Colours (matplotlib names) used throughout, so every figure reads the same way.
CAR_COLOR = "tab:blue"
NONCAR_COLOR = "tab:orange"
RANDOM_COLOR = "tab:gray"
GROUPED_COLOR = "tab:green"
SCALE_COLORS = ("#00e5ff", "#ffea00", "#ff3df5", "#76ff03", "#ff9100", "#ffffff")
BOX_COLOR = "#00ff00"
_ACCENTS = (*SCALE_COLORS, BOX_COLOR, CAR_COLOR, NONCAR_COLOR, RANDOM_COLOR, GROUPED_COLOR, "tab:purple",
            "red", "orange", "#2f7bff", "#bbbbbb", "black", "white")


# --- paths and files ----------------------------------------------------------------------------


@dataclass(frozen=True)
class NotebookPaths:
    """Folders a notebook reads and writes.

    Attributes
    ----------
    repo : Path
        The repository (parent of the notebook folder).
    data : Path
        Training data and videos (``vehicles.zip``, ``videos/``, ``annotations/``).
    output : Path
        Where figures and processed videos are written (created if missing).
    """

    repo: Path
    data: Path
    output: Path

    def __str__(self) -> str:
        def show(path: Path) -> str:
            try:
                return os.path.relpath(path, self.repo)
            except ValueError:  # another drive (Windows)
                return str(path)

        return f"repository {self.repo.name}/, data {show(self.data)}, output {show(self.output)}"


def notebook_paths(notebook_dir: str | os.PathLike | None = None) -> NotebookPaths:
    """The repository, data and output folders, seen from a notebook's folder.

    Data: ``$VEHICLE_DETECTION_DATA``, else ``../shared/data`` beside the checkout when it
    exists, else the repository's ``data/``. Output: ``$VD_OUTPUT_DIR``, else
    ``output_images/``.

    Parameters
    ----------
    notebook_dir : path-like, optional
        The notebook's folder; default the working directory (Jupyter and
        ``tools/regenerate.py`` both run a notebook in its own folder).
    """
    nb = Path(notebook_dir) if notebook_dir is not None else Path.cwd()
    repo = nb.resolve().parent
    shared = repo.parent / "shared" / "data"
    data = default_data_dir() if os.environ.get(DATA_ENV) else shared if shared.is_dir() else repo / "data"
    out = Path(os.environ.get(OUTPUT_ENV) or repo / "output_images")
    out.mkdir(parents=True, exist_ok=True)
    return NotebookPaths(repo=repo, data=Path(data).resolve(), output=out.resolve())


def save_figure(fig, path: str | os.PathLike, *, dpi: int = 100, budget: int = PNG_BUDGET, show: bool | None = None) -> Path:
    """Write a figure as a PNG, trimmed to its content; large ones get a 256-colour palette.

    Photographs make big truecolour PNGs; above ``budget`` bytes the picture is quantised to
    256 colours (median cut), which keeps plots crisp and frames recognisable at about a third
    of the size. The smaller of the two encodings is written.

    With ``show`` (default: when running in a Jupyter kernel) the written PNG is displayed and
    the figure closed, so a notebook shows, and stores, exactly the compact file instead of a
    second, truecolour rendering of the figure.

    Returns
    -------
    Path
        ``path``.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi, bbox_inches="tight", pad_inches=0.05, facecolor="white")
    data = buf.getvalue()
    if len(data) > budget:
        small = io.BytesIO()
        _quantize(Image.open(io.BytesIO(data)).convert("RGB")).save(small, format="PNG", optimize=True)
        if len(small.getvalue()) < len(data):
            data = small.getvalue()
    path.write_bytes(data)
    if show if show is not None else _in_kernel():
        from IPython.display import Image as ShownImage
        from IPython.display import display

        display(ShownImage(data=data, format="png"))
        plt.close(fig)
    return path


def _in_kernel() -> bool:
    """Whether this runs in a Jupyter (IPython) kernel, where figures display inline."""
    ipython = sys.modules.get("IPython")
    shell = ipython.get_ipython() if ipython is not None else None
    return getattr(shell, "kernel", None) is not None


def _quantize(img):
    """256-colour version of an RGB PIL image whose palette holds the figures' accent colours exactly.

    A median-cut palette of a photograph has no room for a few pixels of pure cyan or green:
    box and window outlines would come out in dull look-alikes.
    """
    accents = sorted({tuple(int(round(255 * v)) for v in to_rgb(c)) for c in _ACCENTS})
    base = img.quantize(colors=256 - len(accents), method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE)
    palette = base.getpalette()[: 3 * (256 - len(accents))] + [v for c in accents for v in c]
    ref = Image.new("P", (1, 1))
    ref.putpalette(palette)
    return img.quantize(palette=ref, dither=Image.Dither.NONE)


def markdown_table(rows: Sequence[Mapping], columns: Sequence[tuple[str, str, str]]) -> str:
    """A Markdown table of dict rows.

    Parameters
    ----------
    rows : sequence of mapping
    columns : sequence of (key, header, format)
        ``format`` is a :func:`format` spec such as ``".4f"`` (``""``: ``str``); a value may
        also be a list or tuple, joined with ``,``.
    """

    def cell(v, fmt):
        if isinstance(v, (list, tuple)):
            return ",".join(str(x) for x in v)
        return format(v, fmt) if fmt else str(v)

    head = "| " + " | ".join(h for _, h, _ in columns) + " |"
    rule = "|" + "|".join(" --- " for _ in columns) + "|"
    body = ["| " + " | ".join(cell(r[k], f) for k, _, f in columns) + " |" for r in rows]
    return "\n".join([head, rule, *body])


# --- small drawing helpers ---------------------------------------------------------------------


def _frame_ax(ax, image, title=None, dim: float = 1.0):
    ax.imshow(image if dim == 1.0 else (image * dim).astype(np.uint8))
    ax.set_xticks([])
    ax.set_yticks([])
    if title:
        ax.set_title(title, fontsize=9)


def _boxes(ax, boxes, color=BOX_COLOR, lw=2.0, labels=None, ls="-", fontsize=7):
    for i, (x1, y1, x2, y2) in enumerate(np.asarray(boxes, dtype=float).reshape(-1, 4)):
        ax.add_patch(Rectangle((x1, y1), x2 - x1, y2 - y1, fill=False, ec=color, lw=lw, ls=ls))
        if labels is not None:
            ax.text(x1, y1 - 4, str(labels[i]), color="black", fontsize=fontsize, va="bottom",
                    bbox=dict(fc=color, ec="none", pad=1.0))


def _view(axes, w, h, rows=None):
    """Show pixels ``[0, w) x rows`` (default every row) of a frame in each axis."""
    top, bottom = rows if rows is not None else (0, h)
    for ax in np.ravel(axes):
        ax.set_xlim(0, w)
        ax.set_ylim(bottom, top)


def _tag(ax, text):
    ax.text(0.01, 0.97, text, color="white", fontsize=7, va="top", transform=ax.transAxes, bbox=dict(fc="black", alpha=0.6, pad=1))


def _panel_height(width_in: float, frame_shape, rows) -> float:
    h, w = frame_shape[:2]
    span = (rows[1] - rows[0]) if rows is not None else h
    return width_in * span / w + 0.12


def _heat_norm(vmax: float):
    return PowerNorm(0.5, vmin=0.0, vmax=max(vmax, 1e-6))


def _grid(nrows, ncols, cell_w, cell_h, **kw):
    fig, axes = plt.subplots(nrows, ncols, figsize=(ncols * cell_w, nrows * cell_h), squeeze=False, layout="constrained", **kw)
    return fig, axes


# --- data ---------------------------------------------------------------------------------------


def image_grid(
    images: Sequence[np.ndarray],
    *,
    ncols: int = 8,
    titles: Sequence[str] | None = None,
    row_labels: Sequence[str] | None = None,
    suptitle: str | None = None,
    cell: float = 1.0,
    cmap: str | None = None,
    fontsize: int = 7,
):
    """A contact sheet: images left to right, top to bottom, ``ncols`` per row.

    ``None`` entries leave their cell blank (to start a new row); ``row_labels`` (one per row)
    are written at the left of each row.
    """
    n = len(images)
    nrows = max(1, -(-n // ncols))
    fig, axes = _grid(nrows, ncols, cell, cell * (1.18 if titles else 1.0))
    for k, ax in enumerate(axes.flat):
        ax.set_xticks([])
        ax.set_yticks([])
        if k >= n or images[k] is None:
            ax.axis("off")
            continue
        ax.imshow(images[k], cmap=cmap)
        if titles is not None:
            ax.set_title(titles[k], fontsize=fontsize)
    if row_labels is not None:
        for r, label in enumerate(row_labels):
            axes[r, 0].set_ylabel(label, rotation=0, ha="right", va="center", fontsize=fontsize + 1)
    if suptitle:
        fig.suptitle(suptitle, fontsize=10)
    return fig


def counts_figure(counts: Mapping[str, int], *, duplicates: Mapping[str, int] | None = None):
    """Horizontal bars of patches per source folder, coloured by class.

    ``duplicates`` (files per folder that have a byte-identical twin) is drawn hatched on top.
    """
    names = list(counts)
    values = np.array([counts[k] for k in names])
    colors = [CAR_COLOR if k.startswith("vehicles/") else NONCAR_COLOR for k in names]
    fig, ax = plt.subplots(layout="constrained", figsize=(7.5, 3.2))
    y = np.arange(len(names))[::-1]
    ax.barh(y, values, color=colors)
    if duplicates:
        d = np.array([duplicates.get(k, 0) for k in names])
        ax.barh(y, d, color="none", ec="black", hatch="////", lw=0, label="files with a byte-identical twin")
        ax.legend(loc="center right", fontsize=8)
    for yi, v in zip(y, values):
        ax.text(v + values.max() * 0.01, yi, f"{v:,}", va="center", fontsize=8)
    ax.set_yticks(y, names, fontsize=8)
    ax.set_xlim(0, values.max() * 1.12)
    n_car = sum(v for k, v in counts.items() if k.startswith("vehicles/"))
    ax.set_title(f"Training patches per source folder: {n_car:,} vehicles (blue), {values.sum() - n_car:,} non-vehicles (orange)", fontsize=9)
    ax.set_xlabel("64x64 patches", fontsize=8)
    return fig


# --- features -----------------------------------------------------------------------------------


def color_space_figure(patches: Mapping[str, np.ndarray], color_spaces: Sequence[str] | None = None):
    """Each channel of each patch in each colour space: one row per space, grey levels 0-255.

    ``color_spaces`` defaults to every space :func:`~vehicle_detection.features.convert_color`
    supports.
    """
    color_spaces = COLOR_SPACES if color_spaces is None else color_spaces
    names = list(patches)
    ncols = 1 + 3 * len(names)
    fig, axes = _grid(len(color_spaces), ncols, 1.05, 1.1)
    for r, space in enumerate(color_spaces):
        ax = axes[r, 0]
        ax.axis("off")
        ax.text(0.95, 0.5, space, ha="right", va="center", fontsize=10, transform=ax.transAxes)
        for p, name in enumerate(names):
            conv = convert_color(patches[name], space)
            for c in range(3):
                ax = axes[r, 1 + 3 * p + c]
                ax.imshow(conv[:, :, c], cmap="gray", vmin=0, vmax=255)
                ax.set_xticks([])
                ax.set_yticks([])
                ax.set_title(f"{name} {_channel_names(space)[c]}", fontsize=7)
    fig.suptitle(f"Channels of each patch in {len(color_spaces)} colour spaces (8-bit OpenCV conventions)", fontsize=9)
    return fig


def _channel_names(space: str) -> tuple[str, str, str]:
    return ("Y", "Cr", "Cb") if space == "YCrCb" else tuple(space)  # type: ignore[return-value]


def hog_figure(patches: Mapping[str, np.ndarray], config):
    """Per patch: the RGB patch, then each channel of ``config.color_space`` above its HOG picture."""
    names = list(patches)
    ch_names = _channel_names(config.color_space)
    fig, axes = _grid(2 * len(names), 4, 1.7, 1.75)
    for p, name in enumerate(names):
        conv = convert_color(patches[name], config.color_space)
        top, bottom = axes[2 * p], axes[2 * p + 1]
        top[0].imshow(patches[name])
        top[0].set_title(f"{name} (RGB)", fontsize=8)
        bottom[0].axis("off")
        bottom[0].text(0.5, 0.5, "HOG of the\nchannel above", ha="center", va="center", fontsize=8, transform=bottom[0].transAxes)
        for c in range(3):
            top[c + 1].imshow(conv[:, :, c], cmap="gray")
            top[c + 1].set_title(f"{ch_names[c]} channel", fontsize=8)
            used = c in config.hog_channels
            bottom[c + 1].imshow(hog_image(conv[:, :, c], config), cmap="magma", norm=PowerNorm(0.6))
            bottom[c + 1].set_title(f"HOG {ch_names[c]}" + ("" if used else " (unused)"), fontsize=8)
        for ax in (*top, *bottom):
            ax.set_xticks([])
            ax.set_yticks([])
    o = config.orientations
    fig.suptitle(
        f"HOG per channel, {config.color_space}: {o} {'signed' if config.signed else 'unsigned'} orientations, "
        f"{config.pixels_per_cell}-px cells, {config.cells_per_block}x{config.cells_per_block} blocks"
        + (", sqrt gamma" if config.hog_sqrt else ""),
        fontsize=9,
    )
    return fig


def hog_parameters_figure(patch: np.ndarray, configs: Sequence, *, title: str | None = None):
    """HOG pictures of one patch's first HOG channel under several configurations, with vector lengths."""
    fig, axes = _grid(1, len(configs) + 1, 1.9, 2.25)
    axes = axes[0]
    axes[0].imshow(patch)
    axes[0].set_title("patch", fontsize=8)
    for ax, cfg in zip(axes[1:], configs):
        ch = cfg.hog_channels[0]
        conv = convert_color(patch, cfg.color_space)
        ax.imshow(hog_image(conv[:, :, ch], cfg), cmap="magma", norm=PowerNorm(0.6))
        ax.set_title(
            f"{cfg.orientations} {'signed' if cfg.signed else 'unsigned'}, {cfg.pixels_per_cell}px cells\n"
            f"{cfg.hog_length // len(cfg.hog_channels)} values/channel",
            fontsize=8,
        )
    for ax in axes:
        ax.set_xticks([])
        ax.set_yticks([])
    if title:
        fig.suptitle(title, fontsize=9)
    return fig


def spatial_bins_figure(patches: Mapping[str, np.ndarray], config):
    """Per patch: the RGB patch, its spatial bins shown as a picture, and the bin vector."""
    s = config.spatial_size
    names = list(patches)
    fig = plt.figure(figsize=(10, 1.9 * len(names)), layout="constrained")
    gs = fig.add_gridspec(len(names), 4, width_ratios=[1, 1, 1, 4])
    ch = _channel_names(config.color_space)
    for p, name in enumerate(names):
        conv = convert_color(patches[name], config.color_space)
        vec = bin_spatial(conv, s)
        a0, a1, a2, a3 = (fig.add_subplot(gs[p, i]) for i in range(4))
        a0.imshow(patches[name])
        a0.set_title(name, fontsize=8)
        a1.imshow(bin_spatial(patches[name], s).reshape(s, s, 3).astype(np.uint8), interpolation="nearest")
        a1.set_title(f"RGB binned to {s}x{s}", fontsize=8)
        a2.imshow(vec.reshape(s, s, 3)[:, :, 0], cmap="gray", interpolation="nearest")
        a2.set_title(f"{ch[0]} binned", fontsize=8)
        for a in (a0, a1, a2):
            a.set_xticks([])
            a.set_yticks([])
        for c in range(3):
            a3.plot(np.arange(c, len(vec), 3), vec[c::3], lw=0.8, label=ch[c])
        a3.set_xlim(0, len(vec))
        a3.set_title(f"{config.color_space} spatial features ({len(vec)} values, row-major y, x, channel)", fontsize=8)
        a3.tick_params(labelsize=7)
        a3.legend(fontsize=7, ncol=3, loc="upper right")
    return fig


def histogram_figure(patches: Mapping[str, np.ndarray], config):
    """Colour histograms of each patch, one panel per channel of ``config.color_space``."""
    b = config.hist_bins
    ch = _channel_names(config.color_space)
    fig, axes = _grid(1, 3, 3.2, 2.4)
    width = 256 / b
    centers = (np.arange(b) + 0.5) * width
    for k, (name, patch) in enumerate(patches.items()):
        h = color_histogram(convert_color(patch, config.color_space), b)
        for c in range(3):
            axes[0, c].bar(centers + (k - 0.5) * width * 0.45, h[c * b : (c + 1) * b], width=width * 0.45,
                           color=(CAR_COLOR, NONCAR_COLOR, "tab:purple")[k % 3], label=name)
    for c in range(3):
        axes[0, c].set_title(f"{ch[c]}: {b} bins over 0-255", fontsize=9)
        axes[0, c].set_xlim(0, 256)
        axes[0, c].tick_params(labelsize=7)
        axes[0, c].set_xlabel("value", fontsize=8)
    axes[0, 0].set_ylabel("pixels (of 4096)", fontsize=8)
    axes[0, 0].legend(fontsize=8)
    fig.suptitle(f"Colour histograms in {config.color_space}", fontsize=9)
    return fig


def feature_vector_figure(raw: np.ndarray, scaled: np.ndarray, layout: Mapping[str, slice], *, title: str = ""):
    """The feature vector of one patch before and after standardisation, one column per part.

    The raw parts live on very different scales (each panel of the top row has its own y axis);
    after standardisation they share one (bottom row).
    """
    parts = [(k, sl) for k, sl in layout.items() if sl.stop > sl.start]
    widths = [max(0.8, 3.5 * (sl.stop - sl.start) / len(raw)) for _, sl in parts]
    fig, axes = plt.subplots(2, len(parts), figsize=(10, 4.2), squeeze=False, layout="constrained",
                             gridspec_kw={"width_ratios": widths}, sharey="row")
    shades = {"spatial": "#1f77b4", "hist": "#ff7f0e", "hog": "#2ca02c"}
    axes[0, 0].set_ylabel("raw value (symlog)", fontsize=8)
    axes[1, 0].set_ylabel("standardised\n(x - mean) / std", fontsize=8)
    for c, (part, sl) in enumerate(parts):
        x = np.arange(sl.start, sl.stop)
        for r, vec in enumerate((raw, scaled)):
            ax = axes[r, c]
            ax.plot(x, vec[sl], lw=0.5 if len(x) > 200 else 0.9, color=shades.get(part, "black"))
            ax.set_xlim(sl.start, sl.stop)
            ax.tick_params(labelsize=7)
            ax.axhline(0, color="black", lw=0.4)
        axes[0, c].set_title(f"{part} ({sl.stop - sl.start:,} values)\nraw {raw[sl].min():.3g} .. {raw[sl].max():.3g}", fontsize=8)
        axes[1, c].set_xlabel("feature index", fontsize=7)
    axes[0, 0].set_yscale("symlog", linthresh=0.1)
    if title:
        fig.suptitle(title, fontsize=9)
    return fig


# --- classifier ---------------------------------------------------------------------------------


def accuracy_figure(metrics: Mapping):
    """Accuracy, precision and recall of the random and the grouped split (``model.metrics``)."""
    keys = ("accuracy", "precision", "recall")
    splits = (("random_split", "random split", RANDOM_COLOR), ("grouped_split", "grouped split (no leakage)", GROUPED_COLOR))
    fig, ax = plt.subplots(layout="constrained", figsize=(6.4, 2.9))
    x = np.arange(len(keys))
    vals = []
    for k, (key, label, color) in enumerate(splits):
        m = metrics[key]
        v = [m[q] for q in keys]
        vals += v
        bars = ax.bar(x + (k - 0.5) * 0.38, v, width=0.36, color=color, label=f"{label}: test {m['n_test']:,}")
        for b, val in zip(bars, v):
            ax.text(b.get_x() + b.get_width() / 2, val, f"{val:.4f}", ha="center", va="bottom", fontsize=8)
    ax.set_xticks(x, keys)
    lo = np.floor((min(vals) - 0.005) * 100) / 100
    ax.set_ylim(lo, 1.0 + (1.0 - lo) * 0.3)
    ax.axhline(1.0, color="black", lw=0.5)
    ax.legend(fontsize=8, loc="upper center", ncol=2, frameon=False)
    ax.set_title("Held-out scores of the embedded model's configuration (80/20 splits)", fontsize=9)
    return fig


def showcase_configs(model_config) -> list:
    """The feature configurations notebook 3 and ``tools/sweep_features.py`` compare.

    The classic choices (RGB / HLS / YCrCb, 9 unsigned orientations, 8 or 16-pixel cells, one or
    three HOG channels, with and without colour features), signed orientations, and
    ``model_config`` (the embedded model's).
    """
    classic = dict(signed=False, hog_sqrt=False, spatial_size=16, hist_bins=32)
    return [
        FeatureConfig(color_space="RGB", orientations=9, **classic),
        FeatureConfig(color_space="HLS", orientations=9, **classic),
        FeatureConfig(color_space="YCrCb", orientations=9, **classic),
        FeatureConfig(color_space="YCrCb", orientations=9, pixels_per_cell=16, **classic),
        FeatureConfig(color_space="YCrCb", orientations=9, hog_channels=(0,), **classic),
        FeatureConfig(color_space="YCrCb", orientations=9, signed=False, hog_sqrt=False, spatial_size=0, hist_bins=0),
        FeatureConfig(color_space="YCrCb", orientations=16, signed=True, hog_sqrt=False),
        model_config,
    ]


def sweep_label(row: Mapping) -> str:
    """A short name for a sweep row: colour space, channels, orientations, cell, colour features."""
    ch = "".join(str(c) for c in row["hog_channels"])
    o = f"{row['orientations']}{'s' if row.get('signed') else ''}"
    extra = []
    if row.get("hog_sqrt"):
        extra.append("sqrt")
    extra.append(f"sp{row['spatial_size']}/h{row['hist_bins']}" if row["spatial_size"] or row["hist_bins"] else "HOG only")
    return f"{row['color_space']} ch{ch} o{o} ppc{row['pixels_per_cell']} {' '.join(extra)}"


def sweep_figure(rows: Sequence[Mapping], *, n_images: int | None = None):
    """Random versus grouped accuracy per feature configuration, and feature length."""
    rows = sorted(rows, key=lambda r: r["grouped_accuracy"])
    labels = [sweep_label(r) for r in rows]
    y = np.arange(len(rows))
    fig, (ax, ax2) = plt.subplots(1, 2, layout="constrained", figsize=(10, 0.42 * len(rows) + 1.4), sharey=True, gridspec_kw={"width_ratios": [3, 1]})
    ax.barh(y + 0.2, [r["random_accuracy"] for r in rows], height=0.38, color=RANDOM_COLOR, label="random split")
    ax.barh(y - 0.2, [r["grouped_accuracy"] for r in rows], height=0.38, color=GROUPED_COLOR, label="grouped split")
    for yi, r in zip(y, rows):
        ax.text(r["grouped_accuracy"], yi - 0.2, f" {r['grouped_accuracy']:.3f}", va="center", fontsize=7)
        ax.text(r["random_accuracy"], yi + 0.2, f" {r['random_accuracy']:.3f}", va="center", fontsize=7)
    acc = [r[k] for r in rows for k in ("random_accuracy", "grouped_accuracy")]
    ax.set_xlim(np.floor((min(acc) - 0.01) * 100) / 100, 1.004)
    ax.set_yticks(y, labels, fontsize=8)
    ax.tick_params(axis="x", labelsize=7)
    ax.legend(fontsize=8, loc="lower right")
    ax.set_xlabel("test accuracy", fontsize=8)
    ax2.barh(y, [r["n_features"] for r in rows], color="tab:purple")
    ax2.set_xlabel("features per patch", fontsize=8)
    ax2.tick_params(labelsize=7)
    what = f" on {n_images:,} patches" if n_images else ""
    ax.set_title(f"Feature sweep{what} (80/20 splits, linear SVM)", fontsize=9, loc="left")
    return fig


def confusion_figure(confusion: Mapping[str, int], *, title: str = ""):
    """A 2x2 confusion matrix from ``{'tn', 'fp', 'fn', 'tp'}`` counts, with row percentages."""
    m = np.array([[confusion["tn"], confusion["fp"]], [confusion["fn"], confusion["tp"]]])
    fig, ax = plt.subplots(layout="constrained", figsize=(3.8, 3.3))
    ax.imshow(m / m.sum(axis=1, keepdims=True), cmap="Blues", vmin=0, vmax=1)
    for i in range(2):
        for j in range(2):
            pct = 100 * m[i, j] / m[i].sum()
            ax.text(j, i, f"{m[i, j]:,}\n{pct:.1f}%", ha="center", va="center", fontsize=10,
                    color="white" if pct > 50 else "black")
    ax.set_xticks([0, 1], ["non-vehicle", "vehicle"], fontsize=8)
    ax.set_yticks([0, 1], ["non-vehicle", "vehicle"], fontsize=8)
    ax.set_xlabel("predicted", fontsize=9)
    ax.set_ylabel("true", fontsize=9)
    if title:
        ax.set_title(title, fontsize=9)
    return fig


# --- sliding windows ----------------------------------------------------------------------------


def search_plan_table(frame_shape, plan, config) -> str:
    """A Markdown table of a search plan on frames of ``frame_shape``: one row per scale, and the total.

    Columns: scale, window side, rows searched, step, overlap of neighbouring windows, windows
    (:func:`~vehicle_detection.search.plan_windows`), all in the frame's pixels.
    """
    grids = plan_windows(frame_shape, plan, config)
    f = frame_shape[0] / plan.reference_height
    rows = []
    for s, boxes in zip(plan.scales, grids):
        side = config.window * s.scale * f
        step = s.step * config.pixels_per_cell * s.scale * f
        rows.append({"scale": f"{s.scale:g}", "px": f"{side:.0f}", "rows": f"{s.y_start * f:.0f}-{s.y_stop * f:.0f}",
                     "step": f"{step:.0f}", "overlap": f"{max(0.0, 1 - step / side):.1%}", "n": f"{len(boxes):,}"})
    rows.append({"scale": "all", "px": "", "rows": "", "step": "", "overlap": "", "n": f"{sum(len(b) for b in grids):,}"})
    return markdown_table(rows, [("scale", "scale", ""), ("px", "window (px)", ""), ("rows", "rows searched", ""),
                                 ("step", "step (px)", ""), ("overlap", "overlap", ""), ("n", "windows", "")])


def window_grid_figure(frame: np.ndarray, plan, config, *, ncols: int = 2, rows: tuple[int, int] | None = None):
    """One panel per search scale: its band, a tiling of its windows, and a few neighbours.

    Neighbouring windows (thick, first row of the band) show the step; the thin grid shows
    every ``k``-th window, ``k`` chosen so that drawn windows barely overlap. ``rows`` crops
    the frame shown to ``(top, bottom)`` pixel rows.
    """
    grids = plan_windows(frame.shape, plan, config)
    n = len(plan.scales)
    nrows = -(-n // ncols)
    fig, axes = _grid(nrows, ncols, 5.0, _panel_height(5.0, frame.shape, rows) + 0.2)
    h, w = frame.shape[:2]
    f = h / plan.reference_height
    for k, ax in enumerate(axes.flat):
        if k >= n:
            ax.axis("off")
            continue
        s, boxes = plan.scales[k], grids[k]
        color = SCALE_COLORS[k % len(SCALE_COLORS)]
        _frame_ax(ax, frame, dim=0.55)
        side = config.window * s.scale * f
        step = s.step * config.pixels_per_cell * s.scale * f
        x_stop = w if s.x_stop is None else s.x_stop * f
        ax.add_patch(Rectangle((s.x_start * f, s.y_start * f), x_stop - s.x_start * f, (s.y_stop - s.y_start) * f,
                               fill=False, ec="white", lw=1.2, ls="--"))
        if len(boxes):
            stride = max(1, int(round(side / step)))
            xs, ys = np.unique(boxes[:, 0]), np.unique(boxes[:, 1])
            keep = np.isin(boxes[:, 0], xs[::stride]) & np.isin(boxes[:, 1], ys[::stride])
            _boxes(ax, boxes[keep], color=color, lw=0.6)
            first_row = boxes[boxes[:, 1] == ys[0]]
            mid = len(first_row) // 2
            _boxes(ax, first_row[mid : mid + 4], color=color, lw=2.2)
        overlap = max(0.0, 1 - step / side)
        ax.set_title(
            f"scale {s.scale:g}: {side:.0f}px windows, step {step:.0f}px ({overlap:.1%} overlap)\n"
            f"rows {s.y_start}-{s.y_stop}, {len(boxes):,} windows",
            fontsize=8,
        )
    _view(axes, w, h, rows)
    total = sum(len(b) for b in grids)
    fig.suptitle(f"Search grid per scale ({total:,} windows per frame); thin: every k-th window, thick: 4 neighbours", fontsize=9)
    return fig


def _label_cmap():
    rng = np.random.default_rng(3)
    colors = np.vstack([[0, 0, 0, 0], np.c_[rng.uniform(0.3, 1.0, (63, 3)), np.ones(63)]])
    return ListedColormap(colors)


def detection_stages_figure(
    items: Sequence[tuple[str, np.ndarray, object, object]], detector, *, rows: tuple[int, int] | None = None, scale_legend: bool = True
):
    """One row per image: hot windows by scale, heat map, labelled blobs, final boxes.

    Parameters
    ----------
    items : sequence of (name, frame, windows, found)
        A frame, its hot windows (:meth:`Detector.windows`) and its vehicles
        (:meth:`Detector.detect_image`), both :class:`~vehicle_detection.detections.Detections`.
    detector : Detector
        For its plan (scale names), heat cell size and image threshold.
    rows : (int, int), optional
        Crop every panel to these pixel rows (e.g. the road, ``(360, 720)``).
    """
    cell, thr = detector.config.tracker.cell, detector.config.image_threshold
    plan = detector.config.plan
    fig, axes = _grid(len(items), 4, 3.2, _panel_height(3.2, items[0][1].shape, rows))
    cmap = _label_cmap()
    for r, (name, frame, wins, found) in enumerate(items):
        h, w = frame.shape[:2]
        heat = detector.heat(frame.shape, wins)
        extent = (0, heat.shape[1] * cell, heat.shape[0] * cell, 0)
        _frame_ax(axes[r, 0], frame)
        scale_index = wins.data.get("scale_index", np.zeros(len(wins), np.int64))  # absent when no window is hot
        for k in range(len(plan.scales)):
            _boxes(axes[r, 0], wins.xyxy[scale_index == k], color=SCALE_COLORS[k % len(SCALE_COLORS)], lw=0.7)
        axes[r, 0].set_ylabel(name, fontsize=9)
        _frame_ax(axes[r, 1], frame, dim=0.35)
        peak = float(heat.max())
        axes[r, 1].imshow(np.ma.masked_less_equal(heat, 0), cmap="hot", norm=_heat_norm(max(peak, thr)), extent=extent, interpolation="nearest")
        labels, n = label_heat(heat, thr)
        _frame_ax(axes[r, 2], frame, dim=0.35)
        axes[r, 2].imshow(np.ma.masked_equal(np.where(labels > 0, (labels - 1) % 63 + 1, 0), 0), cmap=cmap, vmin=0, vmax=63, extent=extent, interpolation="nearest")
        _frame_ax(axes[r, 3], frame)
        _boxes(axes[r, 3], found.xyxy, lw=2.0, labels=[f"{s:.1f}" for s in found.score])
        if r == 0:
            axes[r, 0].set_title("hot windows (colour = window size)", fontsize=9)
            axes[r, 1].set_title("heat: 1 + margin per window", fontsize=9)
            axes[r, 2].set_title(f"labelled blobs of heat > {thr:g}", fontsize=9)
            axes[r, 3].set_title("final boxes, peak heat", fontsize=9)
        _tag(axes[r, 0], f"{len(wins)} windows")
        _tag(axes[r, 1], f"peak {peak:.1f}")
        _tag(axes[r, 2], f"{n} blobs")
        _view(axes[r], w, h, rows)
    if scale_legend:
        handles = [Rectangle((0, 0), 1, 1, fc="none", ec=SCALE_COLORS[k % len(SCALE_COLORS)], lw=2) for k in range(len(plan.scales))]
        names = [f"{detector.model.config.window * s.scale:.0f}px" for s in plan.scales]
        fig.legend(handles, names, loc="outside lower center", ncol=len(names), fontsize=8, frameon=False, title="window size", title_fontsize=8)
    return fig


def before_after_figure(items: Sequence[tuple], *, before: str = "before", after: str = "after"):
    """One row per case: the same crop with the labelled cars and the boxes of two detectors.

    Parameters
    ----------
    items : sequence of (title, frame, cars, boxes_before, boxes_after, crop)
        ``cars``, ``boxes_before``, ``boxes_after``: ``(n, 4)`` boxes in frame pixels; ``crop``:
        ``(x1, y1, x2, y2)``, the part of the frame shown.
    before, after : str
        Names of the two detectors (column titles).

    Labels are dashed blue; each column draws its detector's boxes in green with their IoU
    with the best-overlapping label.
    """
    x1, y1, x2, y2 = items[0][5]
    fig, axes = _grid(len(items), 2, 4.4, 4.4 * (y2 - y1) / (x2 - x1) + 0.3)
    for r, (title, frame, cars, b0, b1, crop) in enumerate(items):
        cx1, cy1, cx2, cy2 = crop
        for c, (name, boxes) in enumerate(((before, b0), (after, b1))):
            ax = axes[r, c]
            _frame_ax(ax, frame, title=f"{title}: {name}")
            _boxes(ax, cars, color="#2f7bff", lw=1.6, ls="--")
            boxes = np.asarray(boxes, dtype=float).reshape(-1, 4)
            ious = box_iou(boxes, cars).max(axis=1, initial=0.0) if len(boxes) else np.zeros(0)
            _boxes(ax, boxes, lw=2.0, labels=[f"IoU {v:.2f}" for v in ious])
            ax.set_xlim(cx1, cx2)
            ax.set_ylim(cy2, cy1)
    return fig


def boxes_grid_figure(items: Sequence[tuple[str, np.ndarray, np.ndarray]], *, ncols: int = 3, title: str = "", rows: tuple[int, int] | None = None):
    """Frames with boxes drawn, ``ncols`` per row: ``items`` of (title, frame, boxes)."""
    nrows = -(-len(items) // ncols)
    fig, axes = _grid(nrows, ncols, 4.2, _panel_height(4.2, items[0][1].shape, rows) + 0.15)
    for ax, item in zip(axes.flat, items):
        name, frame, boxes = item
        _frame_ax(ax, frame, title=f"{name}: {plural(len(boxes), 'vehicle')}")
        _boxes(ax, boxes, lw=2.2)
        _view(ax, frame.shape[1], frame.shape[0], rows)
    for ax in list(axes.flat)[len(items):]:
        ax.axis("off")
    if title:
        fig.suptitle(title, fontsize=9)
    return fig


# --- video --------------------------------------------------------------------------------------


def track_frames(detector, frames, first: int, count: int = 6):
    """Run a detector and a new tracker over frames, keeping ``count`` frames from ``first``.

    Returns
    -------
    list of (frame, index, windows, tracked, integrated heat)
        What :func:`frame_sequence_figure` draws: the frame, its index, its hot windows, the
        live confirmed tracks (no back-fill), and a copy of the tracker's integrated heat after
        the frame.
    """
    tracker = detector.new_tracker()
    records = []
    for index, frame in enumerate(itertools.islice(frames, first + count)):
        wins = detector.windows(frame)
        found = detector.track_step(frame.shape, wins, tracker, frame)
        if index >= first:
            records.append((frame, index, wins, found, tracker.state.integrated.copy()))
    return records


def frame_sequence_figure(records: Sequence[tuple], detector, *, rows: tuple[int, int] | None = None):
    """Consecutive frames: hot windows, integrated heat (threshold contour), confirmed tracks.

    Parameters
    ----------
    records : sequence of (frame, index, windows, tracked, integrated heat)
        As :func:`track_frames` returns them.
    detector : Detector
        For the tracker's cell size and threshold.
    rows : (int, int), optional
        Crop every panel to these pixel rows.
    """
    cfg = detector.config.tracker
    cell = cfg.cell
    norm = _heat_norm(max(float(max(r[4].max() for r in records)), cfg.threshold * 2))
    fig, axes = _grid(len(records), 3, 3.6, _panel_height(3.6, records[0][0].shape, rows) + 0.05)
    for r, (frame, index, wins, found, integ) in enumerate(records):
        h, w = frame.shape[:2]
        extent = (0, integ.shape[1] * cell, integ.shape[0] * cell, 0)
        _frame_ax(axes[r, 0], frame)
        _boxes(axes[r, 0], wins.xyxy, color=SCALE_COLORS[0], lw=0.6)
        axes[r, 0].set_ylabel(f"frame {index}", fontsize=9)
        _tag(axes[r, 0], f"{len(wins)} windows")
        _frame_ax(axes[r, 1], frame, dim=0.35)
        axes[r, 1].imshow(np.ma.masked_less_equal(integ, 0), cmap="hot", norm=norm, extent=extent, interpolation="nearest")
        if (integ > cfg.threshold).any():
            yy, xx = (np.mgrid[0 : integ.shape[0], 0 : integ.shape[1]] + 0.5) * cell
            axes[r, 1].contour(xx, yy, integ, levels=[cfg.threshold], colors=SCALE_COLORS[0], linewidths=0.9)
        _tag(axes[r, 1], f"peak {float(integ.max()):.0f}")
        _frame_ax(axes[r, 2], frame)
        _boxes(axes[r, 2], found.xyxy, lw=2.0, labels=[f"car {t}" for t in found.track_id])
        _tag(axes[r, 2], f"{len(found)} reported")
        if r == 0:
            axes[r, 0].set_title("hot windows of the frame", fontsize=9)
            axes[r, 1].set_title(f"integrated heat (decay {cfg.decay:g}), contour at {cfg.threshold:g}", fontsize=9)
            axes[r, 2].set_title(f"live tracks (>= {cfg.min_hits} hits; the video back-fills)", fontsize=9)
        _view(axes[r], w, h, rows)
    return fig


def tracks_timeline_figure(table, n_frames: int, *, title: str = ""):
    """Which track is reported in which frame (tracked :class:`~vehicle_detection.detections.Detections`)."""
    fig, (ax, ax2) = plt.subplots(2, 1, layout="constrained", figsize=(9, 2.8), sharex=True, gridspec_kw={"height_ratios": [2, 1]})
    ids = np.unique(table.track_id)
    for k, tid in enumerate(ids):
        frames = table.frame[table.track_id == tid]
        ax.scatter(frames, np.full(len(frames), k), s=6, marker="s", color=f"C{k % 10}")
    ax.set_yticks(range(len(ids)), [f"car {t}" for t in ids], fontsize=8)
    ax.set_ylim(-0.7, max(len(ids), 1) - 0.3)
    ax.set_title(title or "Reported tracks per frame", fontsize=9, loc="left")
    counts = np.bincount(table.frame, minlength=n_frames)[:n_frames] if len(table) else np.zeros(n_frames, int)
    ax2.step(np.arange(n_frames), counts, where="mid", color="black", lw=1)
    ax2.set_ylabel("boxes", fontsize=8)
    ax2.set_xlabel("frame", fontsize=8)
    ax2.set_xlim(-0.5, n_frames - 0.5)
    ax2.set_ylim(0, max(int(counts.max(initial=0)), 1) + 0.5)
    for a in (ax, ax2):
        a.tick_params(labelsize=7)
        a.grid(axis="x", lw=0.3)
    return fig


def labelled_frames_figure(frames: Mapping[int, np.ndarray], annotations, detections, *, iou_threshold: float = 0.5, ncols: int = 3):
    """Labelled frames with their labels and the reported boxes, coloured by match outcome.

    Labelled cars are blue (dashed when missed), ignore regions grey dotted; detections are
    green when matched at ``iou_threshold``, red when false positives, orange when ignored.
    ``detections`` is a :class:`~vehicle_detection.detections.Detections` with frame indexes.
    """
    idx = [i for i in annotations.frames if i in frames]
    nrows = max(1, -(-len(idx) // ncols))
    fig, axes = _grid(nrows, ncols, 4.2, 2.6)
    for ax, i in zip(axes.flat, idx):
        lab = annotations.frames[i]
        dets = detections.at_frame(i).xyxy
        m = match_frame(dets, lab, iou_threshold=iou_threshold)
        _frame_ax(ax, frames[i], title=f"frame {i}: TP {m.tp}, FP {m.fp}, FN {m.fn}")
        _boxes(ax, lab.ignore, color="#bbbbbb", lw=1.0, ls=":")
        missed = np.zeros(len(lab.cars), bool)
        missed[m.missed] = True
        _boxes(ax, lab.cars[~missed], color="#2f7bff", lw=1.4)
        _boxes(ax, lab.cars[missed], color="#2f7bff", lw=1.4, ls="--")
        _boxes(ax, dets[m.matches[:, 0]] if m.tp else [], color=BOX_COLOR, lw=2.0)
        _boxes(ax, dets[m.false_positives], color="red", lw=2.0)
        _boxes(ax, dets[m.ignored_detections], color="orange", lw=2.0)
    for ax in list(axes.flat)[len(idx):]:
        ax.axis("off")
    fig.suptitle(
        f"Labelled frames: label blue (dashed: missed), ignore grey; detections green = match (IoU >= {iou_threshold:g}), red = false positive, orange = ignored",
        fontsize=8,
    )
    return fig
