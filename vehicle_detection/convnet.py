"""A small convolutional network that scores the sliding-window search's windows, in NumPy.

The linear SVM over HOG features learns the cameras it is shown; a few convolutions learned from
many cameras' cars carry over better (writeup 3.6). The network here scores exactly the windows
of the search plan (:mod:`~vehicle_detection.search`): it is fully convolutional, so one pass
over a scale's resized band scores every window of the band at once, as the HOG search shares
its cells between windows.

Architecture (a window is the model's 64x64 patch, seen at half resolution, 32x32):

====================  ================================  ====================================
layer                 on a 32x32 window                 on a band of ``h x w`` (half: h/2)
====================  ================================  ====================================
3x3 conv, 3->c1       ReLU, 2x2 max pool -> 16x16       stride 2 (4 band pixels)
3x3 conv, c1->c2      ReLU, 2x2 max pool -> 8x8         stride 4 (8 band pixels: one cell)
3x3 conv, c2->c3      ReLU -> 8x8
8x1 conv, c3->c4      ReLU -> 1x8                       valid: one row per window row
1x8 conv, c4->c4      ReLU -> 1x1                       valid: one column per window column
1x1 conv, c4->5       score, and four edge offsets      one output per window (step 1 cell)
====================  ================================  ====================================

Batch normalisation of training is folded into the convolutions' weights. The score is a logit
(> 0: vehicle); the edge offsets move the window onto the vehicle's box, as the box refinement's
(:func:`~vehicle_detection.refine.apply_offsets`).

Three implementations give the same numbers (tests hold them to float32 rounding):
:meth:`ConvNet.forward`, the plain reference (NumPy: each convolution an ``im2col`` and one matrix
product); :meth:`ConvNet.scores`, the one the search runs (OpenCV's DNN module, fed an ONNX graph
built from the same arrays with the ``onnx`` package: about ten times faster); and the network
in the training framework (:mod:`vehicle_detection.training.convnet`), needed only to train.
The model file holds the arrays and a JSON description, never code.
"""

from __future__ import annotations

import json
import threading
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

__all__ = ["ConvNet", "NET_FORMAT", "NET_INPUT", "halve"]

NET_FORMAT = "vehicle-detection-convnet-1"
#: Side of a window as the network sees it: the 64-pixel patch halved.
NET_INPUT = 32
#: The pixel scaling before the first layer: ``(x / 255 - MEAN) / STD``.
MEAN, STD = 0.5, 0.25
#: Largest channel count and layer count a model file may declare.
_MAX_CHANNELS = 256
_LAYERS = (  # (kernel height, kernel width, padding, max pool after)
    (3, 3, 1, True),
    (3, 3, 1, True),
    (3, 3, 1, False),
    (8, 1, 0, False),
    (1, 8, 0, False),
    (1, 1, 0, False),
)
N_OUT = 5


@dataclass(frozen=True, eq=False)
class ConvNet:
    """The window-scoring network: six convolutions' weights and biases, read-only.

    Parameters
    ----------
    weights : tuple of ndarray of float32, shapes (kh, kw, c_in, c_out)
        One per layer of the architecture above (``c_in`` of the first is 3, ``c_out`` of the
        last is 5).
    biases : tuple of ndarray of float32, shapes (c_out,)
    """

    weights: tuple
    biases: tuple
    _nets: threading.local = field(default_factory=threading.local, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if len(self.weights) != len(_LAYERS) or len(self.biases) != len(_LAYERS):
            raise ValueError(f"a ConvNet has {len(_LAYERS)} layers; got {len(self.weights)} weights and {len(self.biases)} biases")
        ws, bs, c_in = [], [], 3
        for k, ((kh, kw, _, _), w, b) in enumerate(zip(_LAYERS, self.weights, self.biases)):
            w = np.array(w, np.float32, copy=True)
            b = np.array(b, np.float32, copy=True)
            c_out = N_OUT if k == len(_LAYERS) - 1 else (w.shape[3] if w.ndim == 4 else -1)
            if w.shape != (kh, kw, c_in, c_out) or not 1 <= c_out <= _MAX_CHANNELS or b.shape != (c_out,):
                raise ValueError(f"layer {k}: weights {w.shape} and bias {b.shape}, expected ({kh}, {kw}, {c_in}, C) and (C,)"
                                 f" with C <= {_MAX_CHANNELS}" + (f" (C = {N_OUT})" if k == len(_LAYERS) - 1 else ""))
            if not (np.all(np.isfinite(w)) and np.all(np.isfinite(b))) or max(np.abs(w).max(), np.abs(b).max(initial=0)) > 1e6:
                raise ValueError(f"layer {k}: weights must be finite numbers of magnitude at most 1e6")
            w.setflags(write=False)
            b.setflags(write=False)
            ws.append(w)
            bs.append(b)
            c_in = c_out
        object.__setattr__(self, "weights", tuple(ws))
        object.__setattr__(self, "biases", tuple(bs))

    # --- persistence ---------------------------------------------------------------------------
    def arrays(self) -> dict[str, np.ndarray]:
        """The arrays a model file stores: ``net_w0..5`` and ``net_b0..5``."""
        out = {}
        for k, (w, b) in enumerate(zip(self.weights, self.biases)):
            out[f"net_w{k}"], out[f"net_b{k}"] = w, b
        return out

    @staticmethod
    def array_names() -> tuple[str, ...]:
        return tuple(f"net_{p}{k}" for k in range(len(_LAYERS)) for p in "wb")

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray]) -> ConvNet:
        """The inverse of :meth:`arrays`; ``ValueError`` for arrays of the wrong shapes or values."""
        for name in cls.array_names():
            a = arrays[name]
            if a.dtype != np.float32:
                raise ValueError(f"array {name} is {a.dtype}, expected float32")
        n = len(_LAYERS)
        return cls(tuple(arrays[f"net_w{k}"] for k in range(n)), tuple(arrays[f"net_b{k}"] for k in range(n)))

    def spec(self) -> dict[str, Any]:
        """The JSON description saved in a model's header."""
        return {"format": NET_FORMAT, "input": NET_INPUT, "mean": MEAN, "std": STD,
                "channels": [int(w.shape[3]) for w in self.weights]}

    @staticmethod
    def check_spec(spec: Any) -> None:
        """``ValueError`` unless ``spec`` is what :meth:`spec` writes for this code's network."""
        if not isinstance(spec, dict) or spec.get("format") != NET_FORMAT or spec.get("input") != NET_INPUT \
                or spec.get("mean") != MEAN or spec.get("std") != STD:
            raise ValueError(f"network description {json.dumps(spec)[:120]} is not {NET_FORMAT} with input {NET_INPUT}")

    # --- inference -----------------------------------------------------------------------------
    def forward(self, image: np.ndarray) -> np.ndarray:
        """Score every window of an image at half resolution.

        Parameters
        ----------
        image : ndarray of uint8, shape (h, w, 3)
            RGB, at the window's scale: a 64-pixel window is 64 pixels of it (a scale's band,
            or a single 64x64 patch). Windows start every 8 pixels (one HOG cell).

        Returns
        -------
        ndarray of float32, shape (h // 8 - 7, w // 8 - 7, 5)
            For the window whose top-left corner is at ``(8 * r, 8 * c)``: its score (a logit)
            and its four edge offsets, in units of the window's side.
        """
        h, w = image.shape[:2]
        if h < 64 or w < 64:
            raise ValueError(f"the network needs at least one 64x64 window; got an image of {w}x{h}")
        return self._forward(halve(image)[None])[0, : h // 8 - 7, : w // 8 - 7]

    def scores(self, image: np.ndarray) -> np.ndarray:
        """:meth:`forward`, run by OpenCV's DNN module (one network per thread)."""
        h, w = image.shape[:2]
        if h < 64 or w < 64:
            raise ValueError(f"the network needs at least one 64x64 window; got an image of {w}x{h}")
        # (x - 255 MEAN) / (255 STD), and HWC to NCHW, in one pass
        blob = cv2.dnn.blobFromImage(halve(image), 1 / (255 * STD), mean=(255 * MEAN,) * 3)
        net = getattr(self._nets, "net", None)
        if net is None:
            net = self._nets.net = cv2.dnn.readNetFromONNX(np.frombuffer(self.onnx_bytes(), np.uint8))
        net.setInput(blob)
        out = net.forward()
        return np.ascontiguousarray(out[0].transpose(1, 2, 0)[: h // 8 - 7, : w // 8 - 7])

    def onnx_bytes(self) -> bytes:
        """The network as an ONNX model (opset 13; input ``x`` of shape (1, 3, h, w), the
        half-resolution pixels scaled as :meth:`forward` scales them)."""
        from onnx import TensorProto, helper, numpy_helper

        nodes, inits, x = [], [], "x"
        last = len(_LAYERS) - 1
        for k, ((kh, kw, pad, pool), w, b) in enumerate(zip(_LAYERS, self.weights, self.biases)):
            inits += [numpy_helper.from_array(np.ascontiguousarray(w.transpose(3, 2, 0, 1)), f"w{k}"),
                      numpy_helper.from_array(b, f"b{k}")]
            nodes.append(helper.make_node("Conv", [x, f"w{k}", f"b{k}"], [f"conv{k}"], kernel_shape=[kh, kw], pads=[pad] * 4))
            x = f"conv{k}"
            if k < last:
                nodes.append(helper.make_node("Relu", [x], [f"relu{k}"]))
                x = f"relu{k}"
            if pool:
                nodes.append(helper.make_node("MaxPool", [x], [f"pool{k}"], kernel_shape=[2, 2], strides=[2, 2]))
                x = f"pool{k}"
        graph = helper.make_graph(
            nodes, "vehicle_windows",
            [helper.make_tensor_value_info("x", TensorProto.FLOAT, [1, 3, "h", "w"])],
            [helper.make_tensor_value_info(x, TensorProto.FLOAT, [1, N_OUT, "rows", "cols"])], inits)
        return helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)]).SerializeToString()

    def score_patches(self, patches: np.ndarray) -> np.ndarray:
        """Scores and edge offsets of 64x64 RGB ``uint8`` patches: float32 ``(N, 5)``.

        Each patch is scored on its own (zeros beyond its border, as in training), in batches.
        """
        patches = np.asarray(patches)
        if patches.ndim != 4 or patches.shape[1:] != (64, 64, 3) or patches.dtype != np.uint8:
            raise ValueError(f"patches must be uint8 (N, 64, 64, 3); got {patches.dtype} {patches.shape}")
        out = np.zeros((len(patches), N_OUT), np.float32)
        for start in range(0, len(patches), 512):
            chunk = patches[start : start + 512]
            half = np.stack([halve(p) for p in chunk])
            out[start : start + len(chunk)] = self._forward(half)[:, 0, 0]
        return out

    def _forward(self, half: np.ndarray) -> np.ndarray:
        """The network over a batch of half-resolution images ``(N, h, w, 3)`` (uint8 or float
        pixel values 0..255): ``(N, h', w', 5)``."""
        x = half.astype(np.float32) * np.float32(1 / (255 * STD)) - np.float32(MEAN / STD)
        last = len(_LAYERS) - 1
        for k, ((_, _, pad, pool), wk, bk) in enumerate(zip(_LAYERS, self.weights, self.biases)):
            x = _conv(x, wk, bk, pad)
            if k < last:
                np.maximum(x, 0, out=x)
            if pool:
                x = _max_pool(x)
        return x


def halve(image: np.ndarray) -> np.ndarray:
    """An RGB ``uint8`` image at half resolution, as the network sees it: each output pixel the
    rounded mean of a 2x2 block (OpenCV's area resize; a last odd row or column is dropped)."""
    h, w = image.shape[:2]
    return cv2.resize(image[: h // 2 * 2, : w // 2 * 2], (w // 2, h // 2), interpolation=cv2.INTER_AREA)


def _conv(x: np.ndarray, w: np.ndarray, b: np.ndarray, pad: int) -> np.ndarray:
    """A 2-D convolution of ``x`` (N, H, W, C_in) with ``w`` (kh, kw, C_in, C_out), zeros
    ``pad`` pixels beyond the border: one im2col and one matrix product (float32)."""
    kh, kw, c_in, c_out = w.shape
    if pad:
        x = np.pad(x, ((0, 0), (pad, pad), (pad, pad), (0, 0)))
    if kh == kw == 1:
        return x @ w[0, 0] + b
    view = sliding_window_view(x, (kh, kw), axis=(1, 2))  # (N, H', W', C_in, kh, kw)
    n, h2, w2 = view.shape[:3]
    cols = view.reshape(n * h2 * w2, c_in * kh * kw)
    flat = w.transpose(2, 0, 1, 3).reshape(c_in * kh * kw, c_out)
    return (cols @ flat + b).reshape(n, h2, w2, c_out)


def _max_pool(x: np.ndarray) -> np.ndarray:
    n, h, w, c = x.shape
    return x[:, : h // 2 * 2, : w // 2 * 2].reshape(n, h // 2, 2, w // 2, 2, c).max(axis=(2, 4))
