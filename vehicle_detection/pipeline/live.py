"""Live detection frame by frame, for libraries that hand over one frame at a time (moviepy).

:class:`MoviepyAdapter` is a callable that takes an RGB frame and returns it with the tracked
vehicles drawn::

    from moviepy import VideoFileClip                  # moviepy 2: pip install "vehicle-detection[moviepy]"
    import vehicle_detection as vd

    adapter = vd.MoviepyAdapter()                      # the embedded model; or MoviepyAdapter(detector)
    clip = VideoFileClip("test_video.mp4")
    clip.image_transform(adapter).write_videofile("out.mp4")
    adapter.detections                                 # the boxes of every frame, one Detections

It runs **live**: each frame is searched and the tracker advanced at once
(:meth:`~vehicle_detection.detector.Detector.step`), without the back-fill of
:func:`~vehicle_detection.pipeline.video.process_video` (which holds frames back ``min_hits - 1``
frames to draw a car from the frame it appeared). A car is therefore drawn from the frame its
track is confirmed, a few frames later than in ``process_video``; use ``process_video`` when the
whole video is at hand.

Frames must come in order, each once. moviepy asks for frame 0 twice (once when the transformed
clip is made, to learn its size, and again when writing): a frame identical to the previous one is
answered from a cache without advancing the tracker. A frame identical to an earlier one (moviepy
reading the clip again from the start, or seeking back) is refused with ``ValueError``: the tracker
cannot go back; make a new adapter (or call :meth:`MoviepyAdapter.reset`) for another pass. A clip
that truly repeats an earlier frame exactly (black frames before and after a cut) can use
``clip.transform(adapter.transform)`` instead, which checks the frame times rather than contents.
"""

from __future__ import annotations

import hashlib

import numpy as np

from ..detections import Detections
from ..detector import Detector
from ..io.images import as_rgb_uint8, check_frame_shape
from ..viz.drawing import draw_detections

__all__ = ["MoviepyAdapter"]


class MoviepyAdapter:
    """Draw tracked vehicles on frames handed over one at a time, in order.

    Parameters
    ----------
    detector : Detector, optional
        Defaults to ``Detector()`` (the embedded model).
    draw : bool
        Return the frame with the boxes drawn (default); False returns the frame unchanged (the
        boxes are still collected in :attr:`detections`).

    Attributes
    ----------
    detections : Detections
        Every box reported so far (``frame``: 0-based index of the frame in the order received).
    """

    def __init__(self, detector=None, *, draw: bool = True) -> None:
        self.detector = detector if detector is not None else Detector()
        self.draw = draw
        self.reset()

    def reset(self) -> None:
        """Start again from the first frame: new tracker, no boxes."""
        self.tracker = self.detector.new_tracker()
        self._found: list = []
        self._seen: dict[bytes, int] = {}
        self._last_in: np.ndarray | None = None
        self._last_out: np.ndarray | None = None
        self._last_t: float | None = None

    @property
    def detections(self):
        return Detections.concatenate(self._found) if self._found else Detections.empty(tracked=True)

    @property
    def frames_processed(self) -> int:
        return len(self._found)

    def _process(self, frame: np.ndarray) -> np.ndarray:
        found = self.detector.step(frame, self.tracker)
        self._found.append(found)
        out = draw_detections(frame, found) if self.draw else frame
        self._last_in, self._last_out = frame.copy(), out
        return out

    def __call__(self, frame) -> np.ndarray:
        """``clip.image_transform(adapter)``: the next frame, with its vehicles drawn.

        The frame is taken as :meth:`~vehicle_detection.detector.Detector.step` takes it (RGB
        ``uint8``; grey, RGBA and ``uint16`` are converted, and the converted frame is returned);
        float, signed, empty or misshapen frames raise :class:`~vehicle_detection.errors.InputError`.
        """
        frame = _frame(frame, f"frame {self.frames_processed}")
        if self._last_in is not None and frame.shape == self._last_in.shape and np.array_equal(frame, self._last_in):
            return self._last_out  # moviepy's second call on the same frame (frame 0)
        digest = hashlib.blake2b(np.ascontiguousarray(frame).tobytes(), digest_size=16).digest()
        if digest in self._seen:
            raise ValueError(
                f"frame {self._seen[digest]} again after {self.frames_processed} frames: frames must come in order, "
                "each once (the tracker cannot go back); use a new MoviepyAdapter (or reset()) for another pass"
            )
        self._seen[digest] = self.frames_processed
        return self._process(frame)

    def transform(self, get_frame, t: float) -> np.ndarray:
        """``clip.transform(adapter.transform)``: like calling the adapter, checking times instead of contents."""
        if self._last_t is not None:
            if t == self._last_t:
                return self._last_out
            if t < self._last_t:
                raise ValueError(
                    f"frame at t={t} s after t={self._last_t} s: frames must come in order (the tracker cannot go back); "
                    "use a new MoviepyAdapter (or reset()) for another pass"
                )
        out = self._process(_frame(get_frame(t), f"frame at t={t} s"))
        self._last_t = t
        return out


def _frame(frame, name: str) -> np.ndarray:
    """``frame`` as RGB ``uint8`` of a shape the search takes, else InputError naming it."""
    frame = as_rgb_uint8(frame, name=name)
    check_frame_shape(frame.shape[0], frame.shape[1], name)
    return frame
