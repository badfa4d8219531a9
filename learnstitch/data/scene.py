"""A procedural street scene per seed, and a vectorised ray caster for it (torch, CPU or CUDA).

Convention: rigjax's world frame, metres — x right, **y down**, z forward; the rig's centre is the
origin, so the ground is the plane ``y = camera_height`` and "up" is ``-y``. Directions need not be
unit length; depths are distances along unit directions. The sky is at infinity (depth ``inf``).

A scene is a few dozen analytic primitives: the ground (a road with markings and pavements),
building blocks (boxes, 5-40 m), near objects at 0.5-6 m that make the parallax — poles
(cylinders), cars (boxes), pedestrians (a cylinder and a head), trees (a trunk and a crown),
signs with text-like glyphs — some of them standing in the seams between cameras. Surfaces get
procedural textures (:mod:`learnstitch.data.textures`) and sun + ambient shading; fog, brightness and
colour temperature vary per scene. :func:`sample_scene` draws a scene from a seed with numpy;
:func:`render` is a pure function of the scene and the rays, evaluated in chunks so that memory
stays bounded, and gives the same bits in any chunking and with any number of threads. Within a
chunk, rays are sorted by direction and each block of them is intersected only with the
primitives it can reach (:func:`_trace`), then shaded grouped by material.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import NamedTuple

import numpy as np
import torch
from torch import Tensor

from .textures import cell_random, fbm, glyphs, stripes

# Materials (one per primitive).
FACADE, CAR, SIGN, POLE, TRUNK, CROWN, PERSON, HEAD = range(8)
_MATERIALS = HEAD + 1
_EPS = 1e-4
RIG_RADIUS = 0.4  # the farthest a rig's camera sits from the centre; near objects keep clear of it


@dataclass(frozen=True)
class Scene:
    """A street scene: primitives, their materials and colours, and the scene's light.

    Boxes are axis-aligned, ``box_min``/``box_max`` ``(nb, 3)``; cylinders are vertical, centre
    ``(x, z)``, radius, and ``y`` from ``cyl_top`` to ``cyl_bottom`` (y down); spheres have a
    centre and radius. ``*_material`` index the material constants; ``*_colour`` are base RGB in
    [0, 1]; ``*_seed`` vary the texture of each primitive.
    """

    seed: int
    camera_height: float
    road_angle: float  # radians: the road runs along (sin, 0, cos) of this angle
    road_half_width: float
    sun: Tensor  # (3,) unit vector towards the sun
    sun_intensity: float
    ambient: float
    sky_horizon: Tensor  # (3,)
    sky_zenith: Tensor  # (3,)
    cloud_cover: float
    fog_density: float  # 1/m
    fog_colour: Tensor  # (3,)
    brightness: float
    white_balance: Tensor  # (3,) colour-temperature gains
    box_min: Tensor
    box_max: Tensor
    box_material: Tensor
    box_colour: Tensor
    box_seed: Tensor
    cyl_centre: Tensor  # (nc, 2) x, z
    cyl_radius: Tensor
    cyl_top: Tensor
    cyl_bottom: Tensor
    cyl_material: Tensor
    cyl_colour: Tensor
    cyl_seed: Tensor
    sph_centre: Tensor
    sph_radius: Tensor
    sph_material: Tensor
    sph_colour: Tensor
    sph_seed: Tensor

    def to(self, device: torch.device | str) -> Scene:
        values = {f.name: getattr(self, f.name) for f in fields(self)}
        return Scene(**{k: v.to(device) if isinstance(v, Tensor) else v for k, v in values.items()})


def _t(values, dtype=torch.float32) -> Tensor:
    return torch.as_tensor(np.asarray(values), dtype=dtype)


def sample_scene(
    seed: int,
    seam_yaws_deg: tuple[float, ...] = (60.0, 180.0, 300.0),
    near_range=(0.5, 6.0),
    building_range=(5.0, 40.0),
) -> Scene:
    """Draw a scene from ``seed`` (numpy's PCG64; the same seed, the same scene).

    ``seam_yaws_deg``: azimuths (rigjax yaw: + to the right of +z) of the seams between cameras;
    one near object stands in each. ``near_range``: how far beyond the rig's cameras (a circle of
    :data:`RIG_RADIUS`) the nearest surface of a near object is, metres.

    The draws come in a fixed order, which every rendered sample depends on: the street, the
    buildings (:func:`_buildings`), the near objects (:func:`_near_objects`), the light
    (:func:`_light`), then the primitives' texture seeds (:func:`_primitive_columns`).
    """
    rng = np.random.default_rng(seed)
    street = _street(rng)
    rows = _Rows([], [], [])
    _buildings(rng, street, building_range, rows)
    _near_objects(rng, street.height, seam_yaws_deg, near_range, rows)
    return Scene(
        seed=int(seed),
        camera_height=street.height,
        road_angle=street.road_angle,
        road_half_width=street.half_width,
        **_light(rng),
        **_primitive_columns(rng, rows),
    )


class _Street(NamedTuple):
    height: float  # the cameras' height above the ground, metres
    road_angle: float  # radians: the road runs along (sin, 0, cos) of this angle
    half_width: float
    along: np.ndarray  # (2,) x, z: the road's direction
    across: np.ndarray  # (2,) x, z: across the road
    offset: float  # the rig's distance from the road's middle, along ``across``


class _Rows(NamedTuple):
    """The scene's primitives as rows, before they become :class:`Scene`'s columns."""

    boxes: list  # (min xyz, max xyz, material, colour)
    cylinders: list  # (x, z, radius, top, bottom, material, colour)
    spheres: list  # (centre xyz, radius, material, colour)


def _street(rng: np.random.Generator) -> _Street:
    height = float(rng.uniform(1.4, 1.9))
    road_angle = float(rng.uniform(0.0, math.pi))
    half_width = float(rng.uniform(3.0, 6.0))
    along, across = (
        np.array([math.sin(road_angle), math.cos(road_angle)]),
        np.array([math.cos(road_angle), -math.sin(road_angle)]),
    )
    offset = float(rng.uniform(-0.5, 0.5)) * half_width  # the rig is somewhere on the road
    return _Street(height, road_angle, half_width, along, across, offset)


def _buildings(rng: np.random.Generator, street: _Street, building_range, rows: _Rows) -> None:
    """Two rows of blocks along the road, beyond the pavements; those whose nearest surface is in
    ``building_range`` (metres from the rig's centre) join ``rows``."""
    height, along, across = street.height, street.along, street.across
    for side in (-1.0, 1.0):
        position = float(rng.uniform(-40.0, -30.0))
        while position < 40.0:
            length, depth, tall = rng.uniform(6.0, 16.0), rng.uniform(6.0, 14.0), rng.uniform(6.0, 25.0)
            setback = street.half_width + 2.5 + rng.uniform(0.0, 6.0) - side * street.offset
            centre = along * (position + length / 2) + across * side * (setback + depth / 2)
            extent = np.abs(along) * length / 2 + np.abs(across) * depth / 2  # axis-aligned bound of the block
            nearest = np.hypot(*centre) - np.max(extent)  # a lower bound of the block's distance
            if building_range[0] <= nearest <= building_range[1]:
                colour = rng.uniform([0.35, 0.3, 0.25], [0.85, 0.8, 0.75])
                rows.boxes.append(
                    (
                        [centre[0] - extent[0], height - tall, centre[1] - extent[1]],
                        [centre[0] + extent[0], height, centre[1] + extent[1]],
                        FACADE,
                        colour,
                    )
                )
            position += length + rng.uniform(0.5, 4.0)


def _near_objects(
    rng: np.random.Generator, height: float, seam_yaws_deg: tuple[float, ...], near_range, rows: _Rows
) -> None:
    """One near object in each seam (within 8 degrees of its yaw), then 8 to 15 anywhere around."""
    for yaw in seam_yaws_deg:
        _near_object(rng, height, rng.uniform(*near_range), math.radians(yaw + rng.uniform(-8.0, 8.0)), rows)
    for _ in range(int(rng.integers(8, 16))):
        _near_object(rng, height, rng.uniform(*near_range), rng.uniform(0.0, 2 * math.pi), rows)


def _near_object(rng: np.random.Generator, height: float, gap: float, azimuth: float, rows: _Rows) -> None:
    """An object whose nearest surface is ``gap`` metres beyond the rig's cameras, at ``azimuth``
    (radians, rigjax yaw): a pole, a car, a person, a tree or a sign, joined to ``rows``."""
    kind = rng.choice(["pole", "car", "person", "tree", "sign"], p=[0.25, 0.25, 0.2, 0.15, 0.15])
    radius = {
        "pole": rng.uniform(0.05, 0.15),
        "person": rng.uniform(0.18, 0.25),
        "tree": rng.uniform(1.0, 2.0),
    }.get(kind, 0.0)
    if kind == "car":
        size = np.array([rng.uniform(1.6, 2.0), rng.uniform(1.3, 1.7), rng.uniform(3.5, 4.8)])
        if rng.random() < 0.5:
            size[[0, 2]] = size[[2, 0]]
        radius = float(np.hypot(size[0], size[2])) / 2
    elif kind == "sign":
        radius = 0.7
    distance = RIG_RADIUS + gap + radius
    x, z = distance * math.sin(azimuth), distance * math.cos(azimuth)
    boxes, cyls, sphs = rows
    if kind == "pole":
        cyls.append((x, z, radius, height - rng.uniform(3.0, 6.0), height, POLE, rng.uniform(0.2, 0.6, 3)))
    elif kind == "car":
        boxes.append(
            (
                [x - size[0] / 2, height - size[1], z - size[2] / 2],
                [x + size[0] / 2, height - 0.15, z + size[2] / 2],
                CAR,
                rng.uniform(0.05, 0.9, 3),
            )
        )
    elif kind == "person":
        tall = rng.uniform(1.5, 1.9)
        cyls.append((x, z, radius, height - tall + 0.25, height, PERSON, rng.uniform(0.05, 0.9, 3)))
        sphs.append(([x, height - tall + 0.12, z], 0.12, HEAD, rng.uniform([0.45, 0.3, 0.2], [0.9, 0.7, 0.55])))
    elif kind == "tree":
        trunk = rng.uniform(2.0, 3.5)
        cyls.append((x, z, rng.uniform(0.1, 0.25), height - trunk, height, TRUNK, np.array([0.35, 0.25, 0.15])))
        sphs.append(([x, height - trunk - 0.8, z], radius, CROWN, rng.uniform([0.1, 0.3, 0.05], [0.3, 0.6, 0.2])))
    else:  # a sign on a pole
        top = height - rng.uniform(2.0, 3.0)
        cyls.append((x, z, 0.05, top, height, POLE, np.array([0.5, 0.5, 0.5])))
        w, h = rng.uniform(0.6, 1.4), rng.uniform(0.4, 0.9)
        half = np.array([w / 2, 0.03]) if rng.integers(2) == 0 else np.array([0.03, w / 2])
        boxes.append(
            ([x - half[0], top - h, z - half[1]], [x + half[0], top, z + half[1]], SIGN, rng.uniform(0.3, 1.0, 3))
        )


def _light(rng: np.random.Generator) -> dict:
    """:class:`Scene`'s light fields: the sun, the sky, fog, brightness and colour temperature."""
    elevation, azimuth = rng.uniform(math.radians(15), math.radians(70)), rng.uniform(0.0, 2 * math.pi)
    sun = np.array(
        [math.cos(elevation) * math.sin(azimuth), -math.sin(elevation), math.cos(elevation) * math.cos(azimuth)]
    )
    temperature = rng.uniform(-1.0, 1.0)  # warm (-) to cool (+)
    fog = float(rng.choice([0.0, rng.uniform(0.002, 0.02)], p=[0.6, 0.4]))
    horizon = rng.uniform([0.65, 0.7, 0.75], [0.85, 0.88, 0.95])
    # In this order: the keyword arguments of a call are evaluated left to right.
    return dict(
        sun=_t(sun),
        sun_intensity=float(rng.uniform(0.6, 0.9)),
        ambient=float(rng.uniform(0.3, 0.5)),
        sky_horizon=_t(horizon),
        sky_zenith=_t(rng.uniform([0.15, 0.3, 0.6], [0.35, 0.5, 0.9])),
        cloud_cover=float(rng.uniform(0.1, 0.7)),
        fog_density=fog,
        fog_colour=_t(horizon * 0.95),
        brightness=float(rng.uniform(0.8, 1.2)),
        white_balance=_t([1.0 - 0.08 * temperature, 1.0, 1.0 + 0.08 * temperature]),
    )


def _primitive_columns(rng: np.random.Generator, rows: _Rows) -> dict:
    """:class:`Scene`'s primitive fields from ``rows``, and a texture seed for each primitive
    (drawn for the boxes, then the cylinders, then the spheres)."""

    def columns(rows, n):
        return [list(c) for c in zip(*rows)] if rows else [[] for _ in range(n)]

    def seeds(n):
        return _t(rng.integers(0, 1 << 20, n), torch.int64)

    bmin, bmax, bmat, bcol = columns(rows.boxes, 4)
    cx, cz, cr, ctop, cbot, cmat, ccol = columns(rows.cylinders, 7)
    sc, sr, smat, scol = columns(rows.spheres, 4)
    return dict(
        box_min=_t(np.reshape(bmin, (-1, 3))),
        box_max=_t(np.reshape(bmax, (-1, 3))),
        box_material=_t(bmat, torch.int64),
        box_colour=_t(np.reshape(bcol, (-1, 3))),
        box_seed=seeds(len(bmin)),
        cyl_centre=_t(np.stack([cx, cz], -1).reshape(-1, 2)),
        cyl_radius=_t(cr),
        cyl_top=_t(ctop),
        cyl_bottom=_t(cbot),
        cyl_material=_t(cmat, torch.int64),
        cyl_colour=_t(np.reshape(ccol, (-1, 3))),
        cyl_seed=seeds(len(cx)),
        sph_centre=_t(np.reshape(sc, (-1, 3))),
        sph_radius=_t(sr),
        sph_material=_t(smat, torch.int64),
        sph_colour=_t(np.reshape(scol, (-1, 3))),
        sph_seed=seeds(len(sc)),
    )


# Bits that do not depend on how torch splits the work (threads, chunk tails): reductions are
# written out, and transcendental functions, whose vectorised and scalar paths may differ in the
# last bit, are evaluated in float64 and rounded to float32.
def _exact(fn, x: Tensor, *args) -> Tensor:
    return fn(x.to(torch.float64), *args).to(torch.float32)


def _dot(a: Tensor, b: Tensor) -> Tensor:
    """Dot product over the last axis (3), written out."""
    a, b = torch.broadcast_tensors(a, b)
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1] + a[..., 2] * b[..., 2]


def _norm(a: Tensor) -> Tensor:
    return torch.sqrt(_dot(a, a))


# ---------------------------------------------------------------------------------------------
# Intersections: (n,) rays against (m,) primitives -> (n, m) distances (inf for a miss).
def _boxes(o: Tensor, d: Tensor, lo: Tensor, hi: Tensor) -> tuple[Tensor, Tensor]:
    """Slab test. Returns the entry distance ``(n, m)`` and the entry axis ``(n, m)``."""
    inv = 1.0 / torch.where(d.abs() < 1e-12, torch.full_like(d, 1e-12), d)
    t1 = (lo[None] - o[:, None]) * inv[:, None]
    t2 = (hi[None] - o[:, None]) * inv[:, None]
    near, axis = torch.minimum(t1, t2).max(dim=-1)
    far = torch.maximum(t1, t2).min(dim=-1).values
    hit = (near <= far) & (near > _EPS)
    return torch.where(hit, near, torch.full_like(near, math.inf)), axis


def _cylinders(o, d, centre, radius, top, bottom) -> tuple[Tensor, Tensor]:
    """Vertical cylinders with a top cap. Returns distance ``(n, m)`` and whether the cap was hit."""
    ox, oz = o[:, None, 0] - centre[None, :, 0], o[:, None, 2] - centre[None, :, 1]
    dx, dz = d[:, None, 0], d[:, None, 2]
    a = (dx * dx + dz * dz).clamp_min(1e-12)
    b = ox * dx + oz * dz
    c = ox * ox + oz * oz - radius[None] ** 2
    disc = b * b - a * c
    root = torch.sqrt(disc.clamp_min(0.0))
    t_side = (-b - root) / a
    y = o[:, None, 1] + t_side * d[:, None, 1]
    side = (disc >= 0) & (t_side > _EPS) & (y >= top[None]) & (y <= bottom[None])
    dy = d[:, None, 1]
    t_cap = (top[None] - o[:, None, 1]) / torch.where(dy.abs() < 1e-12, torch.full_like(dy, 1e-12), dy)
    cx, cz = ox + t_cap * dx, oz + t_cap * dz
    cap = (t_cap > _EPS) & (cx * cx + cz * cz <= radius[None] ** 2)
    inf = torch.full_like(t_side, math.inf)
    t_side, t_cap = torch.where(side, t_side, inf), torch.where(cap, t_cap, inf)
    return torch.minimum(t_side, t_cap), t_cap < t_side


def _spheres(o, d, centre, radius) -> Tensor:
    oc = o[:, None] - centre[None]
    a = _dot(d, d)[:, None]
    b = _dot(oc, d[:, None])
    c = _dot(oc, oc) - radius[None] ** 2
    disc = b * b - a * c
    t = (-b - torch.sqrt(disc.clamp_min(0.0))) / a
    return torch.where((disc >= 0) & (t > _EPS), t, torch.full_like(t, math.inf))


# ---------------------------------------------------------------------------------------------
# Tracing: the closest hit of each ray. Rays are ordered by direction and cut into blocks; a block
# is intersected only with the primitives whose bounding spheres its cone of rays can reach. The
# test is conservative and a ray's distances are computed as they would be against every
# primitive, so culling changes no bit of the result, only the work.
GROUND, BOX, CYLINDER, SPHERE = range(4)  # what a ray hit (the sky: GROUND at infinite depth)
_BLOCK = 256  # rays per culling block
_BINS = (16, 32)  # rows x columns of the direction order's cells


def _inverse(order: Tensor) -> Tensor:
    """The inverse of a permutation."""
    inverse = torch.empty_like(order)
    inverse[order] = torch.arange(order.shape[0], device=order.device)
    return inverse


def _direction_order(d: Tensor) -> Tensor:
    """A permutation that puts rays of similar (unit) direction next to each other: rays sorted by
    cells of :data:`_BINS`, row by row: equal-area rows of ``y``, and columns of a pseudo-angle
    around ``y`` (monotonic in the azimuth ``atan2(x, z)``, cheaper than it)."""
    rows, cols = _BINS
    x, z = d[:, 0], d[:, 2]
    t = z / (x.abs() + z.abs()).clamp_min(1e-30)  # 1 ahead, 0 to the sides, -1 behind
    azimuth = torch.where(x >= 0, 1.0 - t, 3.0 + t) / 4.0  # [0, 1): once around from +z
    row = ((d[:, 1] + 1.0) * (rows / 2)).long().clamp(0, rows - 1)
    return torch.argsort(row * cols + (azimuth * cols).long().clamp(0, cols - 1))


def _reachable(o: Tensor, d: Tensor, centres: Tensor, radii: Tensor) -> Tensor:
    """``(blocks, m)``: whether any ray of a block of :data:`_BLOCK` consecutive rays (unit
    directions) can hit each bounding sphere.

    A ray from ``o`` (within ``r_o`` of the block's mean origin ``o_c``) that hits the sphere
    ``(c, R)`` has its parallel from ``o_c`` pass within ``R + r_o`` of ``c``, so its direction is
    within ``asin((R + r_o) / |c - o_c|)`` of ``c - o_c``; the block's directions lie within
    ``beta`` of their mean. Margins far above float32's rounding.
    """
    blocks = o.shape[0] // _BLOCK
    o, d = o.view(blocks, _BLOCK, 3), d.view(blocks, _BLOCK, 3)
    o_c = o.mean(dim=1)
    r_o = _norm(o - o_c[:, None]).amax(dim=1) * (1 + 1e-4) + 1e-4
    mean = d.sum(dim=1)
    length = _norm(mean)
    mean = mean / length.clamp_min(1e-12)[:, None]
    # The largest angle from the mean, from the largest chord (well conditioned near 0); no cone
    # where the directions cancel.
    chord = _norm(d - mean[:, None]).amax(dim=1)
    beta = 2 * torch.asin((chord.to(torch.float64) / 2).clamp_max(1.0)) + 1e-4
    beta = torch.where(length > 1e-3, beta, math.pi)
    w = centres[None] - o_c.to(torch.float64)[:, None]
    distance = w.norm(dim=-1)
    reach = radii[None] * (1 + 1e-4) + 1e-4 + r_o.to(torch.float64)[:, None]
    alpha = torch.asin((reach / distance.clamp_min(1e-12)).clamp_max(1.0))
    gamma = torch.acos(((w * mean.to(torch.float64)[:, None]).sum(dim=-1) / distance.clamp_min(1e-12)).clamp(-1.0, 1.0))
    return (distance <= reach) | (gamma <= alpha + beta[:, None])


class _Columns(NamedTuple):
    """Every primitive by its column (boxes, then cylinders, then spheres), and the ground as the
    last column (``-1``): its kind, index within the kind, material, base colour and texture seed;
    and the primitives' bounding spheres (``(m, 3)`` centres and ``(m,)`` radii, float64; the
    ground has none)."""

    kind: Tensor
    index: Tensor
    material: Tensor
    colour: Tensor
    seed: Tensor
    centre: Tensor
    radius: Tensor

    @classmethod
    def of(cls, scene: Scene) -> _Columns:
        counts = (scene.box_min.shape[0], scene.cyl_radius.shape[0], scene.sph_radius.shape[0])
        device = scene.box_min.device

        def cat(*values):
            return torch.cat([v.to(device) for v in values])

        box_centre, box_radius = (scene.box_min + scene.box_max) / 2, (scene.box_max - scene.box_min).norm(dim=-1) / 2
        half_height = (scene.cyl_bottom - scene.cyl_top) / 2
        cyl_centre = torch.stack([scene.cyl_centre[:, 0], scene.cyl_top + half_height, scene.cyl_centre[:, 1]], dim=-1)
        cyl_radius = torch.sqrt(scene.cyl_radius**2 + half_height**2)
        return cls(
            kind=torch.tensor(
                [BOX] * counts[0] + [CYLINDER] * counts[1] + [SPHERE] * counts[2] + [GROUND], device=device
            ),
            index=torch.tensor([*range(counts[0]), *range(counts[1]), *range(counts[2]), 0], device=device),
            material=cat(scene.box_material, scene.cyl_material, scene.sph_material, torch.tensor([-1])),
            colour=cat(scene.box_colour, scene.cyl_colour, scene.sph_colour, torch.zeros(1, 3)),
            seed=cat(scene.box_seed, scene.cyl_seed, scene.sph_seed, torch.zeros(1, dtype=torch.int64)),
            centre=cat(box_centre, cyl_centre, scene.sph_centre).to(torch.float64),
            radius=cat(box_radius, cyl_radius, scene.sph_radius).to(torch.float64),
        )


def _trace(scene: Scene, columns: _Columns, o: Tensor, d: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """Closest hit along unit rays ``(n, 3)`` in the scene of ``columns`` (:meth:`_Columns.of`).

    Returns ``depth`` (``inf``: the sky), the :class:`_Columns` column of what was hit (``-1``:
    the ground or the sky), and ``face``: a box's entry axis, or 1 where a cylinder's top cap was
    hit. Ties go to the ground, then to the earlier column (as ``min`` over all of them would).
    """
    n = o.shape[0]
    depth = torch.where(
        d[:, 1] > 1e-9, (scene.camera_height - o[:, 1]) / d[:, 1].clamp_min(1e-9), torch.full_like(d[:, 1], math.inf)
    )
    counts = (scene.box_min.shape[0], scene.cyl_radius.shape[0], scene.sph_radius.shape[0])
    hit, face = (
        torch.full((n,), -1, dtype=torch.int64, device=o.device),
        torch.zeros(n, dtype=torch.int64, device=o.device),
    )
    if n and sum(counts):
        order = _direction_order(d)
        blocks = -(-n // _BLOCK)
        order = torch.cat([order, order[-1:].expand(blocks * _BLOCK - n)])  # the last block repeats its last ray
        o, d, depth = o.index_select(0, order), d.index_select(0, order), depth.index_select(0, order)
        reachable = _reachable(o, d, columns.centre, columns.radius)
        o, d = o.view(blocks, _BLOCK * 3), d.view(blocks, _BLOCK * 3)
        depth = depth.view(blocks, _BLOCK)
        hit = torch.full((blocks, _BLOCK), -1, dtype=torch.int64, device=o.device)
        face = torch.zeros((blocks, _BLOCK), dtype=torch.int64, device=o.device)
        intersect = (
            [
                lambda o, d, k=k: _boxes(o, d, scene.box_min[k : k + 1], scene.box_max[k : k + 1])
                for k in range(counts[0])
            ]
            + [
                lambda o, d, k=k: _cylinders(
                    o,
                    d,
                    scene.cyl_centre[k : k + 1],
                    scene.cyl_radius[k : k + 1],
                    scene.cyl_top[k : k + 1],
                    scene.cyl_bottom[k : k + 1],
                )
                for k in range(counts[1])
            ]
            + [
                lambda o, d, k=k: (_spheres(o, d, scene.sph_centre[k : k + 1], scene.sph_radius[k : k + 1]), 0)
                for k in range(counts[2])
            ]
        )
        for column, fn in enumerate(intersect):
            rows = reachable[:, column].nonzero()[:, 0]
            if rows.numel() == 0:
                continue
            t, f = fn(o.index_select(0, rows).view(-1, 3), d.index_select(0, rows).view(-1, 3))
            t, current = t.view(-1, _BLOCK), depth.index_select(0, rows)
            closer = t < current  # strict: an earlier primitive keeps a tie
            depth.index_copy_(0, rows, torch.where(closer, t, current))
            hit.index_copy_(0, rows, torch.where(closer, column, hit.index_select(0, rows)))
            f = f.view(-1, _BLOCK).long() if isinstance(f, Tensor) else f  # spheres: 0
            face.index_copy_(0, rows, torch.where(closer, f, face.index_select(0, rows)))
        restore = _inverse(order[:n])
        depth, hit, face = (v.view(-1).index_select(0, restore) for v in (depth, hit, face))
    return depth, hit, face


# ---------------------------------------------------------------------------------------------
# Shading.
def _sky(scene: Scene, d: Tensor) -> Tensor:
    up = (-d[:, 1]).clamp(-1.0, 1.0)
    t = _exact(torch.pow, up.clamp_min(0.0), 0.6)
    colour = scene.sky_horizon * (1 - t[:, None]) + scene.sky_zenith * t[:, None]
    colour = torch.where(
        up[:, None] < 0, scene.sky_horizon * 0.8, colour
    )  # below the horizon (never seen past the ground)
    # Clouds: noise on the plane 1 km up, thinning towards the horizon.
    s = 1.0 / up.clamp_min(0.05)
    clouds = fbm(d[:, 0] * s * 2.0, d[:, 2] * s * 2.0, None, scene.seed + 11, octaves=5)
    cover = ((clouds - (1.0 - scene.cloud_cover)) / 0.25).clamp(0.0, 1.0) * (up > 0.02)
    colour = colour * (1 - cover[:, None] * 0.8) + cover[:, None] * 0.8 * torch.tensor(
        [0.95, 0.95, 0.97], device=d.device
    )
    cos_sun = _dot(d, scene.sun)
    glow = _exact(torch.exp, (cos_sun - 1.0) * 40.0) * 0.35 + (cos_sun > math.cos(math.radians(0.6))) * 2.0
    return colour + glow[:, None] * torch.tensor([1.0, 0.95, 0.8], device=d.device)


def _ground_albedo(scene: Scene, p: Tensor) -> Tensor:
    sa, ca = math.sin(scene.road_angle), math.cos(scene.road_angle)
    u = p[:, 0] * sa + p[:, 2] * ca  # along the road
    v = p[:, 0] * ca - p[:, 2] * sa  # across
    grain = fbm(p[:, 0] * 8.0, p[:, 2] * 8.0, None, scene.seed + 1, octaves=4)
    asphalt = 0.18 + 0.12 * grain + 0.06 * fbm(p[:, 0] * 0.5, p[:, 2] * 0.5, None, scene.seed + 2, octaves=3)
    road = asphalt[:, None].expand(-1, 3).clone()
    centre_line = (v.abs() < 0.07) & (stripes(u, 6.0, 0.5) > 0)
    edge = (v.abs() - (scene.road_half_width - 0.3)).abs() < 0.08
    crossing = (stripes(u + 25.0, 60.0, 0.08) > 0) & (stripes(v, 0.9, 0.5) > 0) & (v.abs() < scene.road_half_width)
    marking = centre_line | edge | crossing
    road = torch.where(
        marking[:, None], torch.tensor([0.85, 0.85, 0.8], device=p.device) * (0.9 + 0.1 * grain[:, None]), road
    )
    # Pavement: 0.5 m slabs with grout lines and a colour per slab.
    tile = cell_random(u / 0.5, v / 0.5, scene.seed + 3)
    grout = (stripes(u, 0.5, 0.06) + stripes(v, 0.5, 0.06)) > 0
    slab = (0.45 + 0.2 * tile + 0.1 * grain)[:, None] * torch.tensor([1.0, 0.97, 0.92], device=p.device)
    pavement = torch.where(grout[:, None], slab * 0.55, slab)
    return torch.where((v.abs() < scene.road_half_width)[:, None], road, pavement)


def _surface_albedo(material: int, colour: Tensor, seed: Tensor, p: Tensor, normal: Tensor, scene: Scene) -> Tensor:
    """Albedo of hits on boxes, cylinders or spheres of one material, from the hit points."""
    # In-plane coordinates of a hit: horizontal along the surface (s) and height above the ground (h).
    horizontal = torch.where(normal[:, 0].abs() > normal[:, 2].abs(), p[:, 2], p[:, 0])
    s = horizontal + seed.to(p.dtype) * 0.37
    h = scene.camera_height - p[:, 1]
    device = p.device
    if material == CROWN:  # leaves
        return (
            colour
            * (0.5 + 0.9 * fbm(p[:, 0] * 12.0, p[:, 1] * 12.0, p[:, 2] * 12.0, scene.seed + 10, octaves=3))[:, None]
        )
    if material == TRUNK:  # vertical bark
        return colour * (0.6 + 0.6 * fbm(s * 30.0, h * 3.0, None, scene.seed + 9, octaves=3))[:, None]
    noise = fbm(s * 4.0, h * 4.0, None, scene.seed + 5, octaves=3)  # on the surface's own coordinates
    out = colour * (0.8 + 0.4 * noise[:, None])
    if material == FACADE:  # bricks, and windows 1.2 x 1.5 m on a 2.5 x 3 m grid above the ground floor
        brick = (stripes(h, 0.25, 0.12) + stripes(s + 0.5 * stripes(h, 0.5, 0.5), 0.6, 0.04)) > 0
        wall = torch.where(brick[:, None], out * 0.75, out)
        win_u, win_v = torch.remainder(s, 2.5), torch.remainder(h, 3.0)
        window = (win_u > 0.6) & (win_u < 1.8) & (win_v > 1.0) & (win_v < 2.5) & (h > 2.5)
        lit = cell_random(s / 2.5, h / 3.0, scene.seed + 6)[:, None]
        glass = torch.tensor([0.1, 0.14, 0.2], device=device) + 0.45 * torch.tensor([0.9, 0.8, 0.5], device=device) * (
            lit > 0.8
        )
        return torch.where(window[:, None], glass, wall)
    if material == CAR:  # a dark window band, dark wheels
        car = torch.where(((h > 0.95) & (h < 1.3))[:, None], out * 0.25, out)
        return torch.where((h < 0.45)[:, None], torch.full_like(out, 0.06), car)
    if material == SIGN:  # text-like glyphs
        ink = glyphs(s / 0.12, h / 0.12, scene.seed + 8)
        return torch.where((ink > 0)[:, None], 1.0 - colour * 0.9, colour)
    if material == POLE:
        return out * (0.8 + 0.3 * stripes(h, 1.0, 0.1))[:, None]
    if material == PERSON:  # clothes in horizontal stripes
        return out * (0.6 + 0.4 * stripes(h, 0.2, 0.5))[:, None]
    return out


def _shade(scene: Scene, albedo: Tensor, normal: Tensor) -> Tensor:
    lambert = _dot(normal, scene.sun).clamp_min(0.0)
    return albedo * (scene.ambient + scene.sun_intensity * lambert)[:, None]


def _normals(scene: Scene, kind: int, index: Tensor, face: Tensor, p: Tensor, d: Tensor) -> Tensor:
    """Surface normals at hits ``p`` on primitives of one kind (facing the ray for boxes)."""
    if kind == BOX:
        rows = torch.arange(d.shape[0], device=d.device)
        normal = torch.zeros_like(d)
        normal[rows, face] = -torch.sign(d[rows, face])
        return normal
    if kind == CYLINDER:
        radial = p[:, [0, 2]] - scene.cyl_centre[index]
        radial = radial / torch.sqrt(radial[:, 0] ** 2 + radial[:, 1] ** 2).clamp_min(1e-9)[:, None]
        normal = torch.stack([radial[:, 0], torch.zeros_like(radial[:, 0]), radial[:, 1]], dim=-1)
        return torch.where(face[:, None] == 1, torch.tensor([0.0, -1.0, 0.0], device=d.device), normal)
    if kind == SPHERE:
        return (p - scene.sph_centre[index]) / scene.sph_radius[index][:, None]
    return torch.tensor([0.0, -1.0, 0.0], device=d.device).expand_as(d)  # the ground


def _render_chunk(scene: Scene, columns: _Columns, o: Tensor, d: Tensor) -> tuple[Tensor, Tensor]:
    d = d / _norm(d)[:, None]
    depth, column, face = _trace(scene, columns, o, d)
    # Rays grouped by what they see — the sky, then (kind, material; the ground's material is
    # -1) — so that each group's normals and textures are computed on a contiguous slice.
    materials = _MATERIALS + 1
    group = torch.where(torch.isinf(depth), 0, 1 + columns.kind[column] * materials + columns.material[column] + 1)
    order = torch.argsort(group)
    sizes = torch.bincount(group, minlength=1).tolist()
    o, d, depth, column, face = (v.index_select(0, order) for v in (o, d, depth, column, face))
    p = o + depth.clamp_max(1e6)[:, None] * d
    colour = torch.empty_like(d)
    start = 0
    for g, size in enumerate(sizes):
        rows, start = slice(start, start + size), start + size
        if size == 0:
            continue
        if g == 0:
            colour[rows] = _sky(scene, d[rows])
            continue
        kind, material = divmod(g - 1, materials)
        hit = column[rows]
        normal = _normals(scene, kind, columns.index[hit], face[rows], p[rows], d[rows])
        if kind == GROUND:
            albedo = _ground_albedo(scene, p[rows])
        else:
            albedo = _surface_albedo(material - 1, columns.colour[hit], columns.seed[hit], p[rows], normal, scene)
        colour[rows] = _shade(scene, albedo, normal)
    if scene.fog_density > 0:
        keep = _exact(torch.exp, -scene.fog_density * depth)[:, None]  # 0 at infinity: the sky is all fog colour...
        keep = torch.where(torch.isinf(depth)[:, None], torch.full_like(keep, 0.6), keep)  # ...but stays visible
        colour = colour * keep + scene.fog_colour * (1 - keep)
    colour = (colour * scene.brightness * scene.white_balance).clamp(0.0, 1.0)
    restore = _inverse(order)
    return colour.index_select(0, restore), depth.index_select(0, restore)


def render(scene: Scene, origins: Tensor, directions: Tensor, chunk: int = 1 << 18) -> tuple[Tensor, Tensor]:
    """Colour and depth seen along rays.

    Args:
        origins, directions: ``(..., 3)`` in the scene's frame (see the module docstring); the
            directions need not be unit length. ``origins`` broadcasts against ``directions``.
        chunk: rays per batch; memory grows with ``chunk``.

    Returns:
        ``rgb`` ``(..., 3)`` in [0, 1] and ``depth`` ``(...)`` in metres along the unit ray, ``inf``
        for the sky. The same bits for any ``chunk`` and any number of torch threads.
    """
    origins, directions = torch.broadcast_tensors(origins, directions)
    shape = directions.shape[:-1]
    o, d = origins.reshape(-1, 3).to(torch.float32), directions.reshape(-1, 3).to(torch.float32)
    scene = scene.to(d.device)
    columns = _Columns.of(scene)
    rgb, depth = [], []
    for start in range(0, o.shape[0], chunk):
        c, t = _render_chunk(scene, columns, o[start : start + chunk], d[start : start + chunk])
        rgb.append(c)
        depth.append(t)
    return torch.cat(rgb).reshape(*shape, 3), torch.cat(depth).reshape(shape)
