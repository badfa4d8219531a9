"""The camera's turn in every frame of a clip, from the clip itself
(``learnstitch turns --rig rig.pto --video clip.mp4``): what horizon levelling and a smoothed
heading start from.

Each frame's lenses are matched with a key frame's, each lens with itself (ORB features inside its
image circle, clear of the circle's edge, on views scaled to at most ``TurnsConfig.max_size``
pixels a side). The matched pixels become rays through the rig's calibrated lenses, orientations
included, so that every lens's matches are rays in the rig's frame, and RANSAC fits one essential
matrix to them (:func:`rigjax.calibration.ransac.ransac_turn`): the camera may walk as well as
turn, and near content, which no rotation alone explains, still agrees. A frame's turn is its key
frame's composed with the rotation it holds. The key frame moves on, to the last frame measured,
when a frame keeps fewer than ``rekey_share`` of the inliers the key frame's first match kept (the
view has moved on); a frame that even then keeps fewer than ``min_inliers`` is *lost*: it keeps the
turn of the last frame measured and is counted. Each key frame adds the error of one fit (a few
hundredths of a degree), so the turn drifts slowly over a long clip.

Convention: a frame's turn is the rotation ``R`` taking a ray in the rig's frame at that frame
into the rig's frame at the clip's first stitched frame (``R`` is the identity there), written as
Hugin's yaw, pitch and roll (``R = world_from_cam(yaw, pitch, roll)``, :mod:`rigjax.camera.rotation`).
"""

from __future__ import annotations

import dataclasses
import itertools
import math
import os
import time
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import NamedTuple

import cv2
import jax
import numpy as np

import rigjax
from rigjax.calibration.features import Features, detect, lens_mask, match
from rigjax.calibration.motion import EDGE_SHARE
from rigjax.calibration.ransac import ransac_turn
from rigjax.camera.model import img_to_ray, map_points
from rigjax.errors import ConfigError, RigjaxError
from rigjax.pto.records import crop_circle

from .source import Footage, Layout, VideoError, first_frame, frames_in, rgb_images
from .sync import footage_layout

HEADER = "frame,time_s,yaw_deg,pitch_deg,roll_deg,inliers,key,lost"


@dataclasses.dataclass(frozen=True)
class TurnsConfig:
    """How a clip's turns are measured (module docstring)."""

    max_size: int = 640  # views scaled down to at most this many pixels a side
    max_features: int = 1500  # ORB features per lens and frame
    ratio: float = 0.8  # Lowe's ratio test
    threshold_deg: float = 0.5  # RANSAC: a match is an inlier within this angle of its epipolar plane
    iterations: int = 512
    min_inliers: int = 25  # fewer, even against the frame before: the frame is lost
    rekey_share: float = 0.5  # fewer than this share of the key frame's first inliers: a new key frame

    def __post_init__(self) -> None:
        for name in ("max_size", "max_features", "iterations", "min_inliers"):
            value = getattr(self, name)
            least = 16 if name == "max_size" else 1
            if isinstance(value, bool) or not isinstance(value, int) or value < least:
                raise ConfigError(f"TurnsConfig.{name}: expected a whole number of at least {least}, got {value!r}")
        for name, low, high in (("ratio", 0.0, 1.0), ("threshold_deg", 0.0, 10.0), ("rekey_share", 0.0, 1.0)):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and low < value <= high):
                raise ConfigError(f"TurnsConfig.{name}: expected a number in ({low}, {high}], got {value!r}")


class Turns(NamedTuple):
    """The camera's turn at each frame of a clip (module docstring's convention)."""

    frames: np.ndarray  # (F,) int: the clip's frame indices
    times: np.ndarray  # (F,) seconds
    rotations: np.ndarray  # (F, 3, 3): the rig's frame at each frame -> at the first
    inliers: np.ndarray  # (F,) int: matches that agreed with the frame's turn (0 at the first frame)
    keys: np.ndarray  # (F,) bool: key frames
    lost: np.ndarray  # (F,) bool: frames whose turn was not measured (the one before is kept)

    def ypr(self) -> np.ndarray:
        """``(F, 3)`` Hugin's yaw, pitch and roll of each frame's turn, degrees."""
        with jax.enable_x64(True):
            return np.asarray(rigjax.ypr_from_world_from_cam(np.asarray(self.rotations, np.float64)), np.float64)

    def to_csv(self) -> str:
        """One line a frame under :data:`HEADER`: what :meth:`write` writes and :func:`read_turns` reads."""
        lines = [HEADER]
        for f, t, (y, p, r), n, key, lost in zip(
            self.frames, self.times, self.ypr(), self.inliers, self.keys, self.lost
        ):
            lines.append(f"{int(f)},{t:.6f},{y:.6f},{p:.6f},{r:.6f},{int(n)},{int(key)},{int(lost)}")
        return "\n".join(lines) + "\n"

    def write(self, path: str | os.PathLike) -> Path:
        """Write the turns as CSV (:meth:`to_csv`), atomically."""
        path = Path(path)
        partial = path.with_name(f".{path.name}.partial")
        partial.write_text(self.to_csv())
        os.replace(partial, path)
        return path


def read_turns(path: str | os.PathLike) -> Turns:
    """The :class:`Turns` a :meth:`Turns.write` wrote; a :class:`ConfigError` naming the file and
    line of anything else."""
    path = Path(path)
    try:
        lines = path.read_text().splitlines()
    except (OSError, UnicodeDecodeError) as error:
        raise ConfigError(f"{path}: cannot read the turns ({error})") from None
    if not lines or lines[0].strip() != HEADER:
        raise ConfigError(f"{path}, line 1: expected the header {HEADER!r} (learnstitch turns writes it)")
    rows = []
    for number, line in enumerate(lines[1:], start=2):
        cells = line.split(",")
        try:
            if len(cells) != 8:
                raise ValueError(f"{len(cells)} values")
            row = (int(cells[0]), *(float(c) for c in cells[1:5]), int(cells[5]), int(cells[6]), int(cells[7]))
            if not all(math.isfinite(v) for v in row[1:5]):
                raise ValueError("a value that is not finite")
        except ValueError as error:
            raise ConfigError(f"{path}, line {number}: expected 8 values as in {HEADER!r} ({error})") from None
        rows.append(row)
    if not rows:
        raise ConfigError(f"{path}: no frames after the header")
    table = np.array(rows, dtype=np.float64)
    with jax.enable_x64(True):
        rotations = np.asarray(rigjax.world_from_cam(table[:, 2], table[:, 3], table[:, 4]), np.float64)
    return Turns(
        frames=table[:, 0].astype(np.int64),
        times=table[:, 1],
        rotations=rotations,
        inliers=table[:, 5].astype(np.int64),
        keys=table[:, 6].astype(bool),
        lost=table[:, 7].astype(bool),
    )


class _Lens(NamedTuple):
    camera: rigjax.Camera  # one camera, orientation included: rays in the rig's frame
    scale: float  # the image's pixels per pixel of its view
    size: tuple[int, int]  # the view's (width, height)
    mask: np.ndarray  # the view's (height, width) uint8, 255 where features are detected


def _lenses(project: rigjax.Project, first: Sequence[np.ndarray], config: TurnsConfig) -> list[_Lens]:
    """Each camera's rays, view size and mask. A circular fisheye's mask is its circle (its crop's,
    else the one found in the first frame, else the frame's inscribed circle about its centre shifts)
    less :data:`~rigjax.calibration.motion.EDGE_SHARE` of the radius: the circle's edge stays put
    in the image as the camera turns."""
    cameras = project.cameras()
    lenses = []
    for k, (image, pixels) in enumerate(zip(project.images, first)):
        scale = max(1.0, max(image.width, image.height) / config.max_size)
        size = (max(1, round(image.width / scale)), max(1, round(image.height / scale)))
        circle = None
        if image.projection == int(rigjax.Projection.CIRCULAR_FISHEYE):
            if image.crop is not None:
                cx, cy, radius = crop_circle(image.crop)
            else:
                cx, cy = image.width / 2 - 0.5 + image.d, image.height / 2 - 0.5 + image.e
                radius = min(image.width, image.height) / 2
                try:
                    found = rigjax.find_image_circle([pixels])
                    cx, cy, radius = found.centre[0], found.centre[1], found.radius
                except RigjaxError:
                    pass  # no edge: the inscribed circle
            circle = dict(
                circle_radius=(1.0 - EDGE_SHARE) * radius / scale,
                centre=((cx + 0.5) / scale - 0.5, (cy + 0.5) / scale - 0.5),
            )
        mask = lens_mask(size[0], size[1], **(circle or {}))
        lenses.append(_Lens(cameras.take(k), scale, size, mask))
    return lenses


def _features(lenses: Sequence[_Lens], images: Sequence[np.ndarray], config: TurnsConfig) -> list[Features]:
    out = []
    for lens, pixels in zip(lenses, images):
        view = pixels if lens.scale == 1.0 else cv2.resize(pixels, lens.size, interpolation=cv2.INTER_AREA)
        out.append(detect(view, detector="orb", max_features=config.max_features, mask=lens.mask))
    return out


def _rays(lens: _Lens, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rays in the rig's frame of view pixels ``xy``, and whether each is valid."""
    return map_points(img_to_ray, lens.camera, (xy + 0.5) * lens.scale - 0.5)


def _fit(
    lenses: Sequence[_Lens], key: Sequence[Features], now: Sequence[Features], config: TurnsConfig, seed: int
) -> tuple[np.ndarray, int]:
    """The rotation taking the key frame's rays to this frame's (``now_from_key``) and its inliers."""
    u_key, u_now = [], []
    for lens, a, b in zip(lenses, key, now):
        index = match(a, b, ratio=config.ratio, mutual=True)
        if len(index):
            ray_a, ok_a = _rays(lens, a.xy[index[:, 0]])
            ray_b, ok_b = _rays(lens, b.xy[index[:, 1]])
            u_key.append(ray_a[ok_a & ok_b])
            u_now.append(ray_b[ok_a & ok_b])
    u_key = np.concatenate(u_key) if u_key else np.zeros((0, 3))
    u_now = np.concatenate(u_now) if u_now else np.zeros((0, 3))
    if len(u_key) < 2:
        return np.eye(3), 0
    fit = ransac_turn(u_key, u_now, threshold_deg=config.threshold_deg, iterations=config.iterations, seed=seed)
    return np.asarray(fit.b_from_a, np.float64), int(fit.inliers.sum())


def measure_turns(
    project: rigjax.Project,
    frames: Iterable[tuple[int, Sequence[np.ndarray]]],
    rate: float,
    config: TurnsConfig | None = None,
) -> Turns:
    """The turns (module docstring) of ``frames``: ``(frame index, each camera's image)`` in the
    ``i`` lines' order, one frame after another, at ``rate`` frames a second."""
    config = TurnsConfig() if config is None else config
    lenses = None
    indices, rotations, inliers, lost = [], [], [], []
    keys: list[bool] = []
    key = previous = None  # (features, turn, position in the lists) of the key frame, of the last frame measured
    key_best = 0  # the inliers of the key frame's first match
    for t, images in frames:
        if lenses is None:
            if len(images) != len(project.images):
                raise ConfigError(f"{len(images)} images a frame, but the project has {len(project.images)}")
            lenses = _lenses(project, images, config)
        now = _features(lenses, images, config)
        turn, count, is_lost = np.eye(3), 0, False
        if key is not None:
            b_from_a, count = _fit(lenses, key[0], now, config, seed=t)
            if count < max(config.min_inliers, config.rekey_share * key_best) and previous is not key:
                key = previous  # the view has moved on: the last frame measured is the key
                keys[key[2]] = True
                b_from_a, count = _fit(lenses, key[0], now, config, seed=t)
                key_best = count if count >= config.min_inliers else 0  # else the next frame measured sets it
            if count < config.min_inliers:
                turn, is_lost = previous[1], True
            else:
                turn = key[1] @ b_from_a.T
                key_best = key_best or count
        if not is_lost:  # a lost frame is never a key frame
            previous = (now, turn, len(indices))
        if key is None:
            key = previous
        indices.append(t)
        rotations.append(turn)
        inliers.append(count)
        keys.append(not keys)  # the first frame is the first key frame
        lost.append(is_lost)
    if not indices:
        raise ConfigError("no frames to measure the turns of")
    frames_array = np.asarray(indices, np.int64)
    return Turns(
        frames_array,
        frames_array / float(rate),
        np.stack(rotations),
        np.asarray(inliers, np.int64),
        np.asarray(keys, bool),
        np.asarray(lost, bool),
    )


class TurnsReport(NamedTuple):
    """What :func:`clip_turns` measured."""

    turns: Turns
    seconds: float
    notes: list[str]

    def summary(self, output: str | os.PathLike | None = None) -> str:
        turns = self.turns
        angles = np.degrees(np.arccos(np.clip((np.trace(turns.rotations, axis1=1, axis2=2) - 1) / 2, -1.0, 1.0)))
        fps = len(turns.frames) / self.seconds if self.seconds > 0 else 0.0
        where = f"{output}: " if output is not None else ""
        lost = int(turns.lost.sum())
        lines = [
            *self.notes,
            f"{where}the turns of {len(turns.frames)} frames ({turns.times[0]:.3f}-{turns.times[-1]:.3f} s), "
            f"{int(turns.keys.sum())} key frames, up to {angles.max():.1f} deg from the first; "
            f"{self.seconds:.1f} s ({fps:.1f} fps)",
        ]
        if lost:
            lines.insert(-1, f"warning: {lost} frames lost (fewer than min_inliers matches): each kept the turn before")
        return "\n".join(lines)


def footage_turns(
    project: rigjax.Project, found: Layout, first: int, count: int | None, config: TurnsConfig | None = None
) -> Turns:
    """The turns of rig frames ``first ..`` (``count`` of them; None: to the end) of footage laid
    out as ``found`` (:func:`~learnstitch.video.source.rig_layout`)."""

    footage = Footage(found, first, count)
    frames = ((t, rgb_images(decoded, found)) for t, decoded in footage)
    head = next(frames, None)
    if head is None:
        raise VideoError(f"{found.infos[0].path}: no frame from frame {first} ({first / float(found.rate):.3f} s)")
    return measure_turns(project, itertools.chain([head], frames), float(found.rate), config)


def clip_turns(
    project: rigjax.Project | str | os.PathLike,
    videos: Sequence[str | os.PathLike],
    *,
    time_s: float = 0.0,
    duration: float | None = None,
    offsets: Sequence[int] | None = None,
    config: TurnsConfig | None = None,
) -> TurnsReport:
    """The turns of a rig's clip (one side-by-side file, or one per camera with ``offsets``, as
    :func:`learnstitch.video.stitch_video` takes them), from the frame on screen at ``time_s`` for
    ``duration`` seconds (None: to the end)."""
    started = time.perf_counter()
    if not isinstance(project, rigjax.Project):
        project = rigjax.load_project(project)
    found, notes = footage_layout(project, videos, offsets)
    count = None if duration is None else frames_in(duration, found.rate)
    if count == 0:
        raise VideoError(f"--duration {duration}: no frame to measure")
    turns = footage_turns(project, found, first_frame(time_s, found.rate), count, config)
    return TurnsReport(turns, time.perf_counter() - started, notes)


__all__ = [
    "HEADER",
    "Turns",
    "TurnsConfig",
    "TurnsReport",
    "clip_turns",
    "footage_turns",
    "measure_turns",
    "read_turns",
]
