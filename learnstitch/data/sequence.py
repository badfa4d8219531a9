"""Synthetic video of a 360 rig carried through a street, with the truth of every frame: what a
video stitcher's temporal flicker and quality are judged on.

The rig is the dual-fisheye camera of :func:`learnstitch.data.dual.draw_dual` (``kind="dual"``: two
190-degree fisheyes back to back, side by side in one frame, Hugin's photometry) or the
three-fisheye rig of ``learnstitch demo --fullres`` (``kind="three"``:
:data:`~learnstitch.data.rigs.FULLRES_RIGS` ``tri_d04``, three 185-degree fisheyes 0.4 m out, the
lens and sensor of :class:`~learnstitch.data.config.SynthConfig`). It is drawn as the stills of its
seed draw it, in the street scene of the seed with a near object in each seam, and then carried as a
hand-held 360 camera is (:class:`Motion`): walked along the street at a steady speed, turned about
the vertical at a steady rate, wobbling a little in pitch and roll. Frame 0 is the rig as drawn: its
images are the stills' (:func:`~learnstitch.data.dual.render_dual_frames`' first frame,
:func:`~learnstitch.data.rigs.render_rig`'s fisheyes). Sensor noise is drawn afresh every frame;
the exposure, white balance, gains and vignetting stay as drawn.

The walk heads along the street's axis, either way, unless a near object stands in the way within
the planned ``Motion.duration``: then along the heading nearest the axis (5-degree steps, up to 90
degrees off it) on which every camera stays :data:`CLEARANCE_M` clear of every surface. A seed
with no such heading is a :class:`~rigjax.errors.ConfigError` (rare: about one seed in a hundred
at 1.4 m/s for 4 s).

Convention: rigjax's world frame (x right, **y down**, z forward; :mod:`learnstitch.data.scene`),
metres, the rig's centre at the origin at frame 0. The **rig frame** is the frame of the rig's
fixed calibration (:meth:`SequenceTruth.project`), through which every frame is stitched: the dual
camera's camera 0 as drawn (:meth:`~learnstitch.data.dual.DualTruth.relative`), the three-fisheye
rig's world at frame 0; its origin is the rig's centre. A frame's :class:`Pose` maps it into the
world, ``x_world = world_from_rig @ x_rig + position``. The truth panorama, inverse depth and
visibility of frame ``f`` are in the rig frame at frame ``f``: the panorama turns with the rig, as a
stitch of that frame's images through the project is oriented. Panorama pixels are rigjax's 360 x
180 equirectangular canvas (:func:`~learnstitch.data.rig.pano_rays`: ``(0, 0)`` the centre of the
top-left pixel, the canvas's centre the rig frame's +z).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterator
from typing import NamedTuple

import jax
import numpy as np
import torch

import rigjax
from rigjax import Camera
from rigjax.errors import ConfigError

from .config import SynthConfig
from .dual import NEAR_RANGE, DualTruth, draw_dual
from .rig import RigSample, fisheye_grids, fisheye_rays, jittered, pano_rays
from .rigs import FULLRES_RIGS
from .scene import Scene, render, sample_scene
from .store import to_uint8
from .visibility import REACH_ATOL, REACH_RTOL, directions_to_points

KINDS = ("dual", "three")
CLEARANCE_M = 0.2  # the least distance, metres, from any camera's centre to any surface on the walk
_DEFAULT_SIZE = {"dual": 1440, "three": 1024}
_WOBBLE_HZ = (0.3, 1.5)  # the hand's wobble: three sinusoids per axis, frequencies in this band
_HEADING_STEP_DEG = 5.0


@dataclasses.dataclass(frozen=True)
class Motion:
    """How the rig is carried: ``speed`` metres a second along the walk, ``yaw_rate`` degrees a
    second about the vertical (+: turning right, as rigjax's yaw), a hand's wobble of at most
    ``wobble_deg`` in pitch and in roll (smooth, drawn per seed, 0 at frame 0), ``fps`` frames a
    second. The walk is planned, and kept clear of the scene's objects, for ``duration`` seconds:
    a sequence has at most ``duration * fps + 1`` frames."""

    speed: float = 1.4
    yaw_rate: float = 15.0
    wobble_deg: float = 1.5
    fps: float = 30.0
    duration: float = 4.0

    def __post_init__(self) -> None:
        for name, low in (("speed", 0.0), ("wobble_deg", 0.0), ("fps", None), ("duration", None)):
            value = getattr(self, name)
            if not math.isfinite(value) or (value < low if low is not None else value <= 0.0):
                bound = f">= {low}" if low is not None else "> 0"
                raise ConfigError(f"Motion.{name} must be finite and {bound}, got {value!r}")
        if not math.isfinite(self.yaw_rate):
            raise ConfigError(f"Motion.yaw_rate must be finite, got {self.yaw_rate!r}")
        if self.wobble_deg > 20.0:
            raise ConfigError(f"Motion.wobble_deg is a hand's wobble, at most 20 degrees, got {self.wobble_deg!r}")

    @property
    def max_frames(self) -> int:
        """The most frames the planned walk holds."""
        return int(math.floor(self.duration * self.fps + 1e-9)) + 1


class Pose(NamedTuple):
    """Where the rig is at a frame: ``x_world = world_from_rig @ x_rig + position``."""

    world_from_rig: np.ndarray  # (3, 3)
    position: np.ndarray  # (3,) the rig's centre, world metres


def _ypr_matrix(yaw_deg: float, pitch_deg: float, roll_deg: float) -> np.ndarray:
    """Hugin's ``Ry(yaw) Rx(pitch) Rz(roll)`` in float64 (exactly the identity at zero)."""
    y, p, r = (math.radians(v) for v in (yaw_deg, pitch_deg, roll_deg))
    ry = np.array([[math.cos(y), 0.0, math.sin(y)], [0.0, 1.0, 0.0], [-math.sin(y), 0.0, math.cos(y)]])
    rx = np.array([[1.0, 0.0, 0.0], [0.0, math.cos(p), -math.sin(p)], [0.0, math.sin(p), math.cos(p)]])
    rz = np.array([[math.cos(r), -math.sin(r), 0.0], [math.sin(r), math.cos(r), 0.0], [0.0, 0.0, 1.0]])
    return ry @ rx @ rz


def wobble(wobble_deg: float, seed: int, time: float) -> tuple[float, float]:
    """The hand's pitch and roll at ``time`` seconds, degrees: per axis three sinusoids of the
    seed's frequencies (in 0.3-1.5 Hz), phases and weights, less their value at time 0, scaled so
    that ``|angle| <= wobble_deg`` always."""
    rng = np.random.default_rng([int(seed), 0x3B0])
    hz, phase, weight = (
        rng.uniform(*_WOBBLE_HZ, (2, 3)),
        rng.uniform(0.0, 2 * math.pi, (2, 3)),
        rng.uniform(0.5, 1.0, (2, 3)),
    )
    angles = (weight * (np.sin(2 * math.pi * hz * time + phase) - np.sin(phase))).sum(-1) / (2 * weight.sum(-1))
    return float(wobble_deg * angles[0]), float(wobble_deg * angles[1])


def _turn(motion: Motion, seed: int, frame: int) -> np.ndarray:
    """``(3, 3)`` the rig's rotation at ``frame`` relative to frame 0's, in the world (about the
    rig's centre): the turn about the vertical, then the hand's pitch and roll."""
    time = frame / motion.fps
    return _ypr_matrix(motion.yaw_rate * time, *wobble(motion.wobble_deg, seed, time))


def rig_pose(
    motion: Motion, seed: int, frame: int, start: np.ndarray | None = None, direction: np.ndarray | None = None
) -> Pose:
    """The rig's pose at ``frame`` (``frame / motion.fps`` seconds): ``world_from_rig = T(t) @
    start`` with ``T = Ry(yaw_rate t) Rx(pitch(t)) Rz(roll(t))`` (:func:`wobble`), and the centre
    ``speed t`` metres along the unit ``direction`` from the origin. ``start``: the rig's
    orientation at frame 0 (the identity if None); ``direction``: the walk's, world (+z if None)."""
    if isinstance(frame, bool) or not isinstance(frame, (int, np.integer)) or frame < 0:
        raise ConfigError(f"frame must be an integer >= 0, got {frame!r}")
    start = np.eye(3) if start is None else np.asarray(start, np.float64)
    direction = np.array([0.0, 0.0, 1.0]) if direction is None else np.asarray(direction, np.float64)
    distance = motion.speed * frame / motion.fps
    return Pose(_turn(motion, seed, int(frame)) @ start, distance * direction + 0.0)  # + 0.0: no -0.0


def surface_distance(scene: Scene, points: np.ndarray) -> np.ndarray:
    """``(P,)`` metres from each world point ``(P, 3)`` to the nearest surface of ``scene``: its
    boxes, cylinders (with their caps), spheres and the ground (0 inside a primitive)."""
    points = np.asarray(points, np.float64)
    distances = [scene.camera_height - points[:, 1]]
    for low, high in zip(scene.box_min.double().numpy(), scene.box_max.double().numpy()):
        distances.append(np.linalg.norm(np.maximum(np.maximum(low - points, points - high), 0.0), axis=-1))
    cylinders = zip(
        scene.cyl_centre.double().numpy(),
        scene.cyl_radius.double().numpy(),
        scene.cyl_top.double().numpy(),
        scene.cyl_bottom.double().numpy(),
    )
    for (x, z), radius, top, bottom in cylinders:
        radial = np.maximum(np.hypot(points[:, 0] - x, points[:, 2] - z) - radius, 0.0)
        vertical = np.maximum(np.maximum(top - points[:, 1], points[:, 1] - bottom), 0.0)
        distances.append(np.hypot(radial, vertical))
    for centre, radius in zip(scene.sph_centre.double().numpy(), scene.sph_radius.double().numpy()):
        distances.append(np.maximum(np.linalg.norm(points - centre, axis=-1) - radius, 0.0))
    return np.min(distances, axis=0)


def _walk(scene: Scene, motion: Motion, reach: float, seed: int) -> tuple[np.ndarray, float]:
    """The walk's world direction and its clearance (metres from the farthest camera's sphere,
    ``reach`` from the centre, to the nearest surface over the planned frames)."""
    steps = np.arange(motion.max_frames) * (motion.speed / motion.fps)
    best = -math.inf
    for offset in np.arange(0.0, 90.0 + 1e-9, _HEADING_STEP_DEG):
        angles = {float(offset), float(-offset), float(180.0 + offset), float(180.0 - offset)}
        for angle in sorted(angles, key=lambda a: (abs(a) > 90.0, a < 0, a)):  # the street's way first
            heading = scene.road_angle + math.radians(angle)
            direction = np.array([math.sin(heading), 0.0, math.cos(heading)])
            clearance = float(surface_distance(scene, steps[:, None] * direction).min()) - reach
            if clearance >= CLEARANCE_M:
                return direction, clearance
            best = max(best, clearance)
    raise ConfigError(
        f"seed {seed}: no walk of {steps[-1]:.1f} m from the rig's place keeps its cameras {CLEARANCE_M} m clear "
        f"of the street's objects (at best {best:.2f} m); take another seed, or a shorter Motion.duration or speed"
    )


class _ThreeSensor(NamedTuple):
    """The three-fisheye rig's lens and sensor, as :func:`~learnstitch.data.rigs.render_fisheyes`
    draws them: per-camera gain, the vignetting's strength, the noise, and where frame 0's noise
    comes from (the generator's state after the gains' spread, as ``render_rig`` draws them)."""

    sample: RigSample  # the cameras and centres, world at frame 0
    gain: np.ndarray  # (N,)
    vignetting: float
    noise_std: float
    noise_state: dict


@dataclasses.dataclass(frozen=True)
class SequenceTruth:
    """A rig drawn for a sequence, and its walk (see the module docstring): everything but the
    frames, which :meth:`frames` renders."""

    kind: str
    seed: int
    motion: Motion
    cameras: Camera  # (N,) the rig frame's, NumPy fields: the project's cameras
    centres: np.ndarray  # (N, 3) rig frame, metres
    circle_deg: float  # the image circles' field of view
    scene: Scene
    start: np.ndarray  # (3, 3) world_from_rig at frame 0
    direction: np.ndarray  # (3,) the walk's, world unit vector
    clearance: float  # metres from every camera to every surface on the planned walk, at least
    sensor: DualTruth | _ThreeSensor

    @property
    def world_cameras(self) -> Camera:
        """The cameras in the world at frame 0 (as drawn)."""
        return self.sensor.cameras if self.kind == "dual" else self.sensor.sample.cameras

    @property
    def world_centres(self) -> np.ndarray:
        """``(N, 3)`` the cameras' centres in the world at frame 0."""
        return self.sensor.centres if self.kind == "dual" else self.sensor.sample.centres

    def pose(self, frame: int) -> Pose:
        """The rig's :class:`Pose` at ``frame``."""
        return rig_pose(self.motion, self.seed, frame, self.start, self.direction)

    def project(self, names: tuple[str, ...] | None = None, pano_width: int = 2048) -> rigjax.Project:
        """The rig's fixed calibration: a Hugin project of the true cameras in the rig frame, their
        centres (``#-rigjax centre`` lines) and a 2:1 360-degree canvas ``pano_width`` wide; the dual
        camera's with its exposure, white balance and vignetting (:meth:`DualTruth.project`). Its
        images are named ``names`` (default ``left.png, right.png`` or ``cam0.png`` ...)."""
        if self.kind == "dual":
            return self.sensor.project(names or ("left.png", "right.png"), pano_width)
        names = names or tuple(f"cam{k}.png" for k in range(len(self.centres)))
        return RigSample(self.cameras, self.centres).project((pano_width, pano_width // 2), names)

    def frames(self, count: int, pano_width: int = 2048, device: torch.device | str = "cpu") -> Iterator[SequenceFrame]:
        """The first ``count`` frames (:class:`SequenceFrame`), one at a time, the panorama
        ``pano_width`` wide (2:1), ray cast on ``device``. Same truth, same frames."""
        if (
            isinstance(count, bool)
            or not isinstance(count, (int, np.integer))
            or not 1 <= count <= self.motion.max_frames
        ):
            raise ConfigError(
                f"count must be 1 to {self.motion.max_frames} frames (Motion.duration {self.motion.duration} s at "
                f"{self.motion.fps} fps), got {count!r}"
            )
        if (
            isinstance(pano_width, bool)
            or not isinstance(pano_width, (int, np.integer))
            or pano_width < 16
            or pano_width % 2
        ):
            raise ConfigError(f"pano_width must be an even integer >= 16, got {pano_width!r}")
        return _render_frames(self, int(count), int(pano_width), torch.device(device))


class SequenceFrame(NamedTuple):
    """One frame of a sequence and its truth; the panorama, inverse depth and visibility in the rig
    frame at this frame (see the module docstring)."""

    index: int
    images: list[np.ndarray]  # N (S, S, 3) uint8 RGB: camera k's image
    pano: np.ndarray  # (H, W, 3) uint8 RGB: the scene's light seen from the rig's centre
    inverse_depth: np.ndarray  # (H, W) float32: 1 / metres from the rig's centre, 0 for the sky
    visibility: np.ndarray  # (N, H, W) bool: camera k sees the pixel's scene point (in its circle, unoccluded)
    pose: Pose

    @property
    def side_by_side(self) -> np.ndarray:
        """``(S, N S, 3)`` the images side by side, camera 0 on the left: the dual camera's frame."""
        return np.concatenate(self.images, axis=1)


def draw_sequence(kind: str, seed: int, size: int | None = None, motion: Motion | None = None) -> SequenceTruth:
    """The rig of ``kind`` (``"dual"`` or ``"three"``) and ``seed`` with images ``size`` pixels
    square (default 1440 and 1024), in the seed's street scene, carried by ``motion`` (default
    :class:`Motion`'s). Same arguments, same truth."""
    motion = Motion() if motion is None else motion
    if kind not in KINDS:
        raise ConfigError(f"kind must be one of {KINDS}, got {kind!r}")
    size = _DEFAULT_SIZE[kind] if size is None else size
    if isinstance(size, bool) or not isinstance(size, (int, np.integer)) or size < 8:
        raise ConfigError(f"size must be an integer >= 8 pixels, got {size!r}")
    seed, size = int(seed), int(size)
    if kind == "dual":
        sensor = draw_dual(seed, size)
        scene = sample_scene(seed, seam_yaws_deg=(90.0, 270.0), near_range=NEAR_RANGE)
        c = sensor.cameras
        with jax.enable_x64(True):
            start = np.asarray(rigjax.world_from_cam(c.yaw[0], c.pitch[0], c.roll[0]), np.float64)
        cameras, centres, circle = sensor.relative(), sensor.centres @ start, float(c.hfov[0])
    else:
        shape = dataclasses.replace(FULLRES_RIGS["tri_d04"], size=size)
        sensor = _draw_three_sensor(shape, seed)
        scene = sample_scene(seed, seam_yaws_deg=shape.seams)
        start, cameras, centres, circle = np.eye(3), sensor.sample.cameras, sensor.sample.centres, shape.hfov
    reach = float(np.linalg.norm(centres, axis=-1).max())
    direction, clearance = _walk(scene, motion, reach, seed)
    return SequenceTruth(kind, seed, motion, cameras, centres, circle, scene, start, direction, clearance, sensor)


def _draw_three_sensor(shape, seed: int) -> _ThreeSensor:
    """The cameras and the lens and sensor of ``render_rig(shape, seed, ..., SynthConfig())``,
    drawn in its order: the cameras' jitter, the gains' spread, frame 0's noise, the strengths."""
    photometry = SynthConfig()
    rng = np.random.default_rng([seed, 0x816])
    cameras = jittered(shape.nominal(), rng, 2.0, 1.0)
    count = len(shape.yaws)
    spread = rng.uniform(-1.0, 1.0, count)
    noise_state = rng.bit_generator.state
    rng.standard_normal((count, shape.size, shape.size, 3))  # frame 0's noise, drawn again when rendered
    gain_strength, vignetting = rng.uniform(0.0, 1.0, 2) * (photometry.gain_jitter, photometry.vignetting)
    sample = RigSample(cameras, shape.centres())
    return _ThreeSensor(sample, 1.0 + gain_strength * spread, vignetting, photometry.noise_std, noise_state)


def render_sequence(
    kind: str,
    seed: int,
    frames: int,
    size: int | None = None,
    motion: Motion | None = None,
    pano_width: int = 2048,
    device: torch.device | str = "cpu",
) -> Iterator[SequenceFrame]:
    """``frames`` frames of the sequence of ``kind`` and ``seed`` (:func:`draw_sequence`,
    :meth:`SequenceTruth.frames`), one at a time; stitch them through :func:`sequence_project`."""
    return draw_sequence(kind, seed, size, motion).frames(frames, pano_width, device)


def sequence_project(
    kind: str,
    seed: int,
    size: int | None = None,
    pano_width: int = 2048,
    names: tuple[str, ...] | None = None,
    motion: Motion | None = None,
) -> rigjax.Project:
    """The fixed calibration every frame of :func:`render_sequence` is stitched through
    (:meth:`SequenceTruth.project`)."""
    return draw_sequence(kind, seed, size, motion).project(names, pano_width)


def _render_frames(truth: SequenceTruth, count: int, pano_width: int, device: torch.device) -> Iterator[SequenceFrame]:
    """:meth:`SequenceTruth.frames`: the rays of the images and the panorama are cast once (the
    world's at frame 0) and turned and moved with the rig each frame."""
    scene = truth.scene.to(device)
    rays, inside, theta = fisheye_rays(truth.world_cameras, truth.circle_deg)
    image_rays = [rays[k][inside[k]] for k in range(len(rays))]  # (M_k, 3) inside camera k's circle
    pano_rig = pano_rays(pano_width, pano_width // 2)  # (H, W, 3) rig frame
    pano_world = pano_rig @ truth.start.T  # frame 0's world
    expose = _dual_exposer(truth, inside) if truth.kind == "dual" else _three_exposer(truth, inside, theta, device)
    for frame in range(count):
        pose = truth.pose(frame)
        turn = _turn(truth.motion, truth.seed, frame)  # pose.world_from_rig = turn @ truth.start
        centres = truth.world_centres @ turn.T + pose.position  # as the stills have them at frame 0
        lights = []
        for k, directions in enumerate(image_rays):
            colour, _ = render(scene, _float32(centres[k], device), _float32(directions @ turn.T, device))
            lights.append(colour)
        images = expose(frame, lights)
        colour, depth = render(scene, _float32(pose.position, device), _float32(pano_world @ turn.T, device))
        depth = depth.cpu()
        inverse_depth = torch.where(torch.isfinite(depth), 1.0 / depth, torch.zeros_like(depth))
        visibility = _visibility(truth, scene, pano_rig, depth, pose, centres, device)
        yield SequenceFrame(frame, images, to_uint8(colour.permute(2, 0, 1)), inverse_depth.numpy(), visibility, pose)


def _float32(values: np.ndarray, device: torch.device) -> torch.Tensor:
    return torch.as_tensor(values, dtype=torch.float32).to(device)


def _dual_exposer(truth: SequenceTruth, inside: np.ndarray):
    """Light -> the dual camera's 8-bit images, as :func:`render_dual_frames` makes them: Hugin's
    vignetting, exposure and white balance, noise from the same stream (``[seed, 4747]``)."""
    lens: DualTruth = truth.sensor
    size = inside.shape[-1]
    xy = np.stack(np.meshgrid(np.arange(size), np.arange(size)), -1).astype(np.float64)
    r2 = ((xy - (size - 1) / 2.0) ** 2).sum(-1) / (2.0 * (size / 2.0) ** 2)  # Hugin's r^2, in half diagonals
    rng = np.random.default_rng([truth.seed, 4747])

    def expose(frame: int, lights: list[torch.Tensor]) -> list[np.ndarray]:
        images = []
        for k, colour in enumerate(lights):
            light = np.zeros((size, size, 3))
            light[inside[k]] = colour.double().cpu().numpy()
            gain = (1.0 + lens.vignetting_b * r2) * 2.0 ** -lens.exposure_value[k]
            balance = np.array([lens.white_balance[k, 0], 1.0, lens.white_balance[k, 1]])
            pixels = light * gain[..., None] * balance + rng.normal(0.0, 0.01, light.shape)
            images.append(np.round(255 * np.clip(pixels, 0.0, 1.0) * inside[k][..., None]).astype(np.uint8))
        return images

    return expose


def _three_exposer(truth: SequenceTruth, inside: np.ndarray, theta: np.ndarray, device: torch.device):
    """Light -> the three-fisheye rig's 8-bit images, as :func:`render_fisheyes` makes them: gain,
    vignetting towards the circle's edge, noise (frame 0's ``render_rig``'s; then ``[seed, 0x816,
    frame]``'s)."""
    sensor: _ThreeSensor = truth.sensor
    masks = torch.as_tensor(inside).to(device)
    gain = torch.as_tensor(sensor.gain, dtype=torch.float32).to(device)
    edge = torch.as_tensor(np.clip(theta / (truth.circle_deg / 2.0), 0.0, 1.0), dtype=torch.float32).to(device)
    falloff = 1.0 - sensor.vignetting * edge**2

    def expose(frame: int, lights: list[torch.Tensor]) -> list[np.ndarray]:
        fisheyes = torch.zeros(*inside.shape, 3, device=device)
        for k, colour in enumerate(lights):
            fisheyes[k][masks[k]] = colour
        if frame == 0:
            rng = np.random.Generator(np.random.PCG64())
            rng.bit_generator.state = sensor.noise_state
        else:
            rng = np.random.default_rng([truth.seed, 0x816, frame])
        noise = torch.as_tensor(rng.standard_normal(fisheyes.shape), dtype=torch.float32).to(device) * sensor.noise_std
        fisheyes = (fisheyes * gain[:, None, None, None] * falloff[..., None] + noise).clamp(0.0, 1.0) * masks[
            ..., None
        ]
        return [to_uint8(fisheye.permute(2, 0, 1)) for fisheye in fisheyes]

    return expose


def _visibility(
    truth: SequenceTruth, scene: Scene, pano_rig: np.ndarray, depth: torch.Tensor, pose: Pose, centres, device
) -> np.ndarray:
    """``(N, H, W)`` which cameras see each panorama pixel's point, as
    :func:`~learnstitch.data.visibility.rig_sight_lines` has it, in the rig frame at this frame:
    inside the camera's circle (its rig-frame direction through the project's camera) and reached
    by a ray cast from its centre (world ``centres``) in the world."""
    rays = torch.as_tensor(pano_rig)
    depth = depth.to(torch.float64)
    rig_centres = torch.as_tensor(truth.centres, dtype=torch.float64)
    directions = directions_to_points(rays, depth, rig_centres)  # (N, H, W, 3) rig frame
    _, inside, _ = fisheye_grids(truth.cameras, directions.numpy(), truth.circle_deg)
    distance = torch.where(
        torch.isfinite(depth), (depth[..., None] * rays - rig_centres[:, None, None]).norm(dim=-1), torch.inf
    )
    world_from_rig = torch.as_tensor(pose.world_from_rig)
    reached = torch.full(distance.shape, torch.inf, dtype=torch.float64)  # cast only where a camera could see
    for k in range(len(centres)):
        towards = (directions[k][inside[k]] @ world_from_rig.T).float().to(device)
        reached[k][inside[k]] = render(scene, _float32(centres[k], device), towards)[1].cpu().to(torch.float64)
    unoccluded = torch.where(
        torch.isinf(distance), torch.isinf(reached), reached >= distance * (1.0 - REACH_RTOL) - REACH_ATOL
    )
    return (inside & unoccluded).numpy()
