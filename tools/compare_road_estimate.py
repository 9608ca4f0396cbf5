"""Lanes and distances from the footage alone, against the chessboard-calibrated camera; and on another dashcam.

    python tools/compare_road_estimate.py [--data ../shared/data] [--cache DIR] [--figure FIG.png]

For clip A and ``test_video.mp4``: the bird's-eye transform estimated from each video without any
camera file (:func:`vehicle_detection.road.autocamera.estimate_birds_eye_from_video`, frames used as
they are) against the calibrated run (the camera and transform that
``vehicle-detection calibrate DATA/camera_cal --straight DATA/lanes/straight_lines1.jpg
DATA/lanes/straight_lines2.jpg --out cam.json`` makes; frames undistorted). Per frame, each
setup's :class:`~vehicle_detection.road.lanes.LaneTracker` gives the radius of curvature and the
offset; the tracked boxes of one detection run (frames as decoded) get a distance from each
transform (the calibrated one after undistorting the box's bottom centre). Printed: the share
of frames whose radii agree within a factor of 1.5, the share (and the largest difference) of
offsets within 0.25 m, and the share of tracked boxes whose distances agree within 20 %.

For the highway clip (another camera, no calibration): the estimate, the share of frames with a
lane, and, for each track that approaches (its distance falls by 5 m or more), how monotonic its
distance is. ``--figure`` writes the highway figure (:func:`vehicle_detection.road.autocamera.road_figure`);
the clip's licence is unknown: keep the figure out of the repository.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]


def calibrated_camera(data: Path):
    from vehicle_detection.road.camera import calibrate
    from vehicle_detection.io.images import read_image
    from vehicle_detection.road.lanes import birds_eye_from_straight

    cam = calibrate(data / "camera_cal")
    frames = [read_image(data / "lanes" / f"straight_lines{i}.jpg") for i in (1, 2)]
    return cam.replace(birds_eye=birds_eye_from_straight(frames, cam))


def lanes_per_frame(path: Path, birds_eye, camera=None) -> list:
    from vehicle_detection.road.lanes import LaneTracker
    from vehicle_detection.io.video import read_frames

    tracker = LaneTracker(birds_eye)
    return [tracker.step(camera.undistort(f) if camera is not None else f) for f in read_frames(path)]


def tracked_boxes(path: Path, cache: Path | None):
    """Every tracked box of the video (frames as decoded), cached as a boxes CSV."""
    from vehicle_detection.pipeline.video import process_video
    from vehicle_detection.io.tables import read_boxes_csv

    if cache is not None:
        csv = cache / f"{path.stem}_boxes.csv"
        if csv.is_file():
            return read_boxes_csv(csv)
        cache.mkdir(parents=True, exist_ok=True)
        process_video(path, None, tables={"csv": csv}, progress=False)
        return read_boxes_csv(csv)
    return process_video(path, None, progress=False)


def bottom_centres(xyxy: np.ndarray) -> np.ndarray:
    return np.c_[(xyxy[:, 0] + xyxy[:, 2]) / 2, xyxy[:, 3]]


def compare(path: Path, cam, cache: Path | None) -> dict:
    from vehicle_detection.road.autocamera import estimate_birds_eye_from_video

    auto, estimate = estimate_birds_eye_from_video(path)
    print(f"\n== {path.name}")
    print("\n".join(estimate.summary()))
    if auto is None:
        return {}
    cal_lanes = lanes_per_frame(path, cam.birds_eye, cam)
    auto_lanes = lanes_per_frame(path, auto)
    both = [(c, a) for c, a in zip(cal_lanes, auto_lanes) if c is not None and a is not None]
    n = len(cal_lanes)
    print(f"frames {n}; a lane in {sum(c is not None for c in cal_lanes)} (calibrated) and "
          f"{sum(a is not None for a in auto_lanes)} (from the footage); both: {len(both)}")
    rc = np.array([c.radius_m for c, _ in both])
    ra = np.array([a.radius_m for _, a in both])
    ratio = np.maximum(ra / rc, rc / ra)
    within = ratio <= 1.5
    straight = (rc > 10_000) & (ra > 10_000)  # both drawn as "straight"
    print(f"radius of curvature within a factor of 1.5: {within.mean():.0%} of {len(both)} frames "
          f"({(within | straight).mean():.0%} counting both above 10 km, drawn 'straight', as agreeing); "
          f"median radius {np.median(rc):.0f} m calibrated, {np.median(ra):.0f} m from the footage; median ratio {np.median(ratio):.2f}")
    oc = np.array([c.offset_m for c, _ in both])
    oa = np.array([a.offset_m for _, a in both])
    d = np.abs(oa - oc)
    print(f"lane-centre offset within 0.25 m: {(d <= 0.25).mean():.0%} of frames; largest difference {d.max():.2f} m, "
          f"median {np.median(d):.2f} m (offsets: calibrated {oc.min():+.2f} to {oc.max():+.2f} m)")
    table = tracked_boxes(path, cache)
    tracked = table.track_id >= 0 if table.track_id is not None else np.zeros(len(table), bool)
    pts = bottom_centres(table.xyxy[tracked].astype(np.float64))
    da = auto.ground_distance(pts)
    dc = cam.birds_eye.ground_distance(cam.undistort_points(pts))
    ok = np.isfinite(da) & np.isfinite(dc) & (dc > 0) & (dc <= 150) & (da <= 150)
    rel = np.abs(da[ok] / dc[ok] - 1)
    print(f"distances of tracked cars within 20 %: {(rel <= 0.2).mean():.0%} of {ok.sum()} boxes "
          f"(median difference {np.median(rel):.1%}, 90th percentile {np.percentile(rel, 90):.1%}; "
          f"calibrated distances {dc[ok].min():.0f} to {dc[ok].max():.0f} m)")
    return {"radius": within.mean(), "offset": (d <= 0.25).mean(), "distance": (rel <= 0.2).mean()}


def highway(path: Path, cache: Path | None, figure: Path | None) -> None:
    from scipy.stats import spearmanr

    from vehicle_detection.road.autocamera import estimate_birds_eye_from_video, road_figure
    from vehicle_detection.road.distance import DistanceTracker
    from vehicle_detection.io.video import probe_video, read_frames

    print(f"\n== {path.name} (no calibration exists)")
    auto, estimate = estimate_birds_eye_from_video(path)
    print("\n".join(estimate.summary()))
    if auto is None:
        return
    lanes = lanes_per_frame(path, auto)
    n = len(lanes)
    fresh = sum(lane is not None and lane.fresh for lane in lanes)
    print(f"a lane drawn in {sum(lane is not None for lane in lanes)} of {n} frames ({fresh} fitted on the frame itself, "
          "the others the last good fit, kept up to 5 frames)")
    # where the lines are visible: the frames whose own paint shows both lines of the lane (no neighbours pooled)
    from vehicle_detection.road.autocamera import frame_lines, paint_segments

    w, h = auto.image_size
    width = np.polyval(estimate.right_line, h) - np.polyval(estimate.left_line, h)
    visible, agree = [], []
    for i, f in enumerate(read_frames(path)):
        fl = frame_lines(paint_segments(f), estimate.vanishing_point, (w, h), i)
        if fl is None or abs(fl.width_px / width - 1) > 0.2:
            continue
        visible.append(i)
        if lanes[i] is not None:
            xw = auto.to_warped([[fl.bottom[0], h], [fl.bottom[1], h]])[:, 0]
            agree.append(abs((auto.vehicle_x - xw.mean()) * auto.xm_per_px - lanes[i].offset_m) <= 0.3)
    drawn = sum(lanes[i] is not None for i in visible)
    print(f"  both lines visible (the estimator's own per-frame detection) in {len(visible)} frames: a lane drawn in {drawn} "
          f"({drawn / max(1, len(visible)):.0%}), its offset within 0.3 m of the visible lines' in {sum(agree)} of them; "
          f"a lane drawn in {sum(lane is not None for lane in lanes) - drawn} of the {n - len(visible)} other frames")
    radius = np.array([lane.radius_m for lane in lanes if lane is not None])
    offset = np.array([lane.offset_m for lane in lanes if lane is not None])
    print(f"  radius: median {np.median(radius):.0f} m; offset {np.percentile(offset, 5):+.2f} to {np.percentile(offset, 95):+.2f} m (5th to 95th percentile)")
    table = DistanceTracker(auto, probe_video(path).fps).update(tracked_boxes(path, cache))
    dist = table.data["distance_m"]
    approaching = []
    for t in np.unique(table.track_id[table.track_id >= 0]):
        sel = (table.track_id == t) & np.isfinite(dist)
        if sel.sum() < 10:
            continue
        fr, d = table.frame[sel], dist[sel]
        order = np.argsort(fr)
        fr, d = fr[order], d[order]
        if d[: max(1, len(d) // 5)].mean() - d[-max(1, len(d) // 5) :].mean() < 5:
            continue
        rho = spearmanr(fr, d)[0]
        steps = np.diff(d)
        approaching.append((t, fr, d))
        print(f"  track {t}: frames {fr[0]}-{fr[-1]} ({len(d)} boxes), {d[0]:.1f} m -> {d[-1]:.1f} m; Spearman rho {rho:+.2f}; "
              f"frame-to-frame rises {np.mean(steps > 0):.0%} of steps, largest rise {max(steps.max(), 0):.1f} m, "
              f"rises above 1 m: {int(np.sum(steps > 1))}")
    if not approaching:
        print("  no track approaches by 5 m or more")
    if figure is not None:
        from vehicle_detection.viz.plots import save_figure

        t, fr, d = max(approaching, key=lambda a: len(a[1])) if approaching else (None, None, None)
        picks = [int(fr[0]), int(fr[len(fr) // 2]), int(fr[-1])] if t is not None else [0, n // 2, n - 1]
        frames = {}
        for i, f in enumerate(read_frames(path)):
            if i in picks:
                frames[i] = f
        shown = [frames[i] for i in picks]
        dets = [table[table.frame == i] for i in picks]
        curves = {f"track {a[0]}": (a[1], a[2]) for a in approaching[:4]} or None
        fig = road_figure(shown, auto, estimate, lanes=[lanes[i] for i in picks], detections=dets,
                          titles=[f"frame {i}" for i in picks], distances=curves)
        save_figure(fig, figure)
        print(f"figure: {figure}")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=REPO.parent / "shared" / "data")
    parser.add_argument("--cache", type=Path, default=None, help="keep the detection runs' boxes here (reused on the next run)")
    parser.add_argument("--figure", type=Path, default=None, help="write the highway figure here (PNG; not into the repository)")
    args = parser.parse_args(argv)
    cam = calibrated_camera(args.data)
    print(f"calibrated: {cam!r}; bird's-eye {100 * cam.birds_eye.xm_per_px:.2f} x {100 * cam.birds_eye.ym_per_px:.2f} cm/px")
    for video in (args.data / "videos" / "project_video_clip_A.mp4", REPO / "test_video.mp4"):
        if video.is_file():
            compare(video, cam, args.cache)
        else:
            print(f"\n== {video}: not found, skipped")
    hw = args.data / "videos" / "highway_dashcam_854x480.mp4"
    if hw.is_file():
        highway(hw, args.cache, args.figure)
    else:
        print(f"\n== {hw}: not found, skipped")
    return 0


if __name__ == "__main__":
    sys.exit(main())
