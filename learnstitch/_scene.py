"""A procedural street scene per seed, and a vectorised ray caster for it (torch, CPU or CUDA).

Convention: rigjax's world frame, metres — x right, **y down**, z forward; the rig's centre is the
origin, so the ground is the plane ``y = camera_height`` and "up" is ``-y``. Directions need not be
unit length; depths are distances along unit directions. The sky is at infinity (depth ``inf``).

A scene is a few dozen analytic primitives: the ground (a road with markings and pavements),
building blocks (boxes, 5-40 m), near objects at 0.5-6 m that make the parallax — poles
(cylinders), cars (boxes), pedestrians (a cylinder and a head), trees (a trunk and a crown),
signs with text-like glyphs — some of them standing in the seams between cameras. Surfaces get
procedural textures (:mod:`learnstitch._textures`) and sun + ambient shading; fog, brightness and
colour temperature vary per scene. :func:`sample_scene` draws a scene from a seed with numpy;
:func:`render` is a pure function of the scene and the rays, evaluated in chunks so that memory
stays bounded, and gives the same bits in any chunking and with any number of threads.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np
import torch
from torch import Tensor

from ._textures import cell_random, fbm, glyphs, stripes

# Materials (one per primitive).
FACADE, CAR, SIGN, POLE, TRUNK, CROWN, PERSON, HEAD = range(8)
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

    def to(self, device: torch.device | str) -> "Scene":
        values = {f.name: getattr(self, f.name) for f in fields(self)}
        return Scene(**{k: v.to(device) if isinstance(v, Tensor) else v for k, v in values.items()})


def _t(values, dtype=torch.float32) -> Tensor:
    return torch.as_tensor(np.asarray(values), dtype=dtype)


def sample_scene(seed: int, seam_yaws_deg: tuple[float, ...] = (60.0, 180.0, 300.0), near_range=(0.5, 6.0),
                 building_range=(5.0, 40.0)) -> Scene:  # fmt: skip
    """Draw a scene from ``seed`` (numpy's PCG64; the same seed, the same scene).

    ``seam_yaws_deg``: azimuths (rigjax yaw: + to the right of +z) of the seams between cameras;
    one near object stands in each. ``near_range``: how far beyond the rig's cameras (a circle of
    :data:`RIG_RADIUS`) the nearest surface of a near object is, metres.
    """
    rng = np.random.default_rng(seed)
    height = float(rng.uniform(1.4, 1.9))
    road_angle = float(rng.uniform(0.0, math.pi))
    half_width = float(rng.uniform(3.0, 6.0))
    along, across = np.array([math.sin(road_angle), math.cos(road_angle)]), np.array([math.cos(road_angle), -math.sin(road_angle)])
    offset = float(rng.uniform(-0.5, 0.5)) * half_width  # the rig is somewhere on the road
    boxes, cyls, sphs = [], [], []  # (min, max, material, colour) / (x, z, r, top, bottom, ...) / (c, r, ...)

    def xz(distance, azimuth):
        return np.array([distance * math.sin(azimuth), distance * math.cos(azimuth)])

    # Buildings: two rows along the road, beyond the pavements.
    for side in (-1.0, 1.0):
        position = float(rng.uniform(-40.0, -30.0))
        while position < 40.0:
            length, depth, tall = rng.uniform(6.0, 16.0), rng.uniform(6.0, 14.0), rng.uniform(6.0, 25.0)
            setback = half_width + 2.5 + rng.uniform(0.0, 6.0) - side * offset
            centre = along * (position + length / 2) + across * side * (setback + depth / 2)
            extent = np.abs(along) * length / 2 + np.abs(across) * depth / 2  # axis-aligned bound of the block
            nearest = np.hypot(*centre) - np.max(extent)  # a lower bound of the block's distance
            if building_range[0] <= nearest <= building_range[1]:
                colour = rng.uniform([0.35, 0.3, 0.25], [0.85, 0.8, 0.75])
                boxes.append(([centre[0] - extent[0], height - tall, centre[1] - extent[1]],
                              [centre[0] + extent[0], height, centre[1] + extent[1]], FACADE, colour))  # fmt: skip
            position += length + rng.uniform(0.5, 4.0)

    def near_object(gap, azimuth):
        """An object whose nearest surface is ``gap`` metres beyond the rig's cameras."""
        kind = rng.choice(["pole", "car", "person", "tree", "sign"], p=[0.25, 0.25, 0.2, 0.15, 0.15])
        radius = {"pole": rng.uniform(0.05, 0.15), "person": rng.uniform(0.18, 0.25), "tree": rng.uniform(1.0, 2.0)}.get(kind, 0.0)
        if kind == "car":
            size = np.array([rng.uniform(1.6, 2.0), rng.uniform(1.3, 1.7), rng.uniform(3.5, 4.8)])
            if rng.random() < 0.5:
                size[[0, 2]] = size[[2, 0]]
            radius = float(np.hypot(size[0], size[2])) / 2
        elif kind == "sign":
            radius = 0.7
        x, z = xz(RIG_RADIUS + gap + radius, azimuth)
        if kind == "pole":
            cyls.append((x, z, radius, height - rng.uniform(3.0, 6.0), height, POLE, rng.uniform(0.2, 0.6, 3)))
        elif kind == "car":
            boxes.append(([x - size[0] / 2, height - size[1], z - size[2] / 2],
                          [x + size[0] / 2, height - 0.15, z + size[2] / 2], CAR, rng.uniform(0.05, 0.9, 3)))  # fmt: skip
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
            boxes.append(([x - half[0], top - h, z - half[1]], [x + half[0], top, z + half[1]], SIGN,
                          rng.uniform(0.3, 1.0, 3)))  # fmt: skip

    for yaw in seam_yaws_deg:
        near_object(rng.uniform(*near_range), math.radians(yaw + rng.uniform(-8.0, 8.0)))
    for _ in range(int(rng.integers(8, 16))):
        near_object(rng.uniform(*near_range), rng.uniform(0.0, 2 * math.pi))

    elevation, azimuth = rng.uniform(math.radians(15), math.radians(70)), rng.uniform(0.0, 2 * math.pi)
    sun = np.array([math.cos(elevation) * math.sin(azimuth), -math.sin(elevation), math.cos(elevation) * math.cos(azimuth)])
    temperature = rng.uniform(-1.0, 1.0)  # warm (-) to cool (+)
    fog = float(rng.choice([0.0, rng.uniform(0.002, 0.02)], p=[0.6, 0.4]))
    horizon = rng.uniform([0.65, 0.7, 0.75], [0.85, 0.88, 0.95])

    def columns(rows, n):
        return [list(c) for c in zip(*rows)] if rows else [[] for _ in range(n)]

    bmin, bmax, bmat, bcol = columns(boxes, 4)
    cx, cz, cr, ctop, cbot, cmat, ccol = columns(cyls, 7)
    sc, sr, smat, scol = columns(sphs, 4)

    def seeds(n):
        return _t(rng.integers(0, 1 << 20, n), torch.int64)

    return Scene(
        seed=int(seed), camera_height=height, road_angle=road_angle, road_half_width=half_width,
        sun=_t(sun), sun_intensity=float(rng.uniform(0.6, 0.9)), ambient=float(rng.uniform(0.3, 0.5)),
        sky_horizon=_t(horizon), sky_zenith=_t(rng.uniform([0.15, 0.3, 0.6], [0.35, 0.5, 0.9])),
        cloud_cover=float(rng.uniform(0.1, 0.7)), fog_density=fog, fog_colour=_t(horizon * 0.95),
        brightness=float(rng.uniform(0.8, 1.2)),
        white_balance=_t([1.0 - 0.08 * temperature, 1.0, 1.0 + 0.08 * temperature]),
        box_min=_t(np.reshape(bmin, (-1, 3))), box_max=_t(np.reshape(bmax, (-1, 3))), box_material=_t(bmat, torch.int64),
        box_colour=_t(np.reshape(bcol, (-1, 3))), box_seed=seeds(len(bmin)),
        cyl_centre=_t(np.stack([cx, cz], -1).reshape(-1, 2)), cyl_radius=_t(cr), cyl_top=_t(ctop), cyl_bottom=_t(cbot),
        cyl_material=_t(cmat, torch.int64), cyl_colour=_t(np.reshape(ccol, (-1, 3))), cyl_seed=seeds(len(cx)),
        sph_centre=_t(np.reshape(sc, (-1, 3))), sph_radius=_t(sr), sph_material=_t(smat, torch.int64),
        sph_colour=_t(np.reshape(scol, (-1, 3))), sph_seed=seeds(len(sc)),
    )  # fmt: skip


# Bits that do not depend on how torch splits the work (threads, chunk tails): reductions are
# written out, and transcendental functions, whose vectorised and scalar paths may differ in the
# last bit, are evaluated in float64 and rounded to float32.
def _exact(fn, x: Tensor, *args) -> Tensor:
    return fn(x.to(torch.float64), *args).to(torch.float32)


def _dot(a: Tensor, b: Tensor) -> Tensor:
    """Dot product over the last axis (3), written out."""
    a, b = torch.broadcast_tensors(a, b)
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1] + a[..., 2] * b[..., 2]


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


def _closest(t: Tensor) -> tuple[Tensor, Tensor]:
    if t.shape[1] == 0:
        return torch.full(t.shape[:1], math.inf, dtype=t.dtype, device=t.device), torch.zeros(t.shape[:1], dtype=torch.int64, device=t.device)
    value, index = t.min(dim=1)
    return value, index


# ---------------------------------------------------------------------------------------------
# Shading.
def _sky(scene: Scene, d: Tensor) -> Tensor:
    up = (-d[:, 1]).clamp(-1.0, 1.0)
    t = _exact(torch.pow, up.clamp_min(0.0), 0.6)
    colour = scene.sky_horizon * (1 - t[:, None]) + scene.sky_zenith * t[:, None]
    colour = torch.where(up[:, None] < 0, scene.sky_horizon * 0.8, colour)  # below the horizon (never seen past the ground)
    # Clouds: noise on the plane 1 km up, thinning towards the horizon.
    s = 1.0 / up.clamp_min(0.05)
    clouds = fbm(d[:, 0] * s * 2.0, d[:, 2] * s * 2.0, None, scene.seed + 11, octaves=5)
    cover = ((clouds - (1.0 - scene.cloud_cover)) / 0.25).clamp(0.0, 1.0) * (up > 0.02)
    colour = colour * (1 - cover[:, None] * 0.8) + cover[:, None] * 0.8 * torch.tensor([0.95, 0.95, 0.97], device=d.device)
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
    edge = ((v.abs() - (scene.road_half_width - 0.3)).abs() < 0.08)
    crossing = (stripes(u + 25.0, 60.0, 0.08) > 0) & (stripes(v, 0.9, 0.5) > 0) & (v.abs() < scene.road_half_width)
    marking = centre_line | edge | crossing
    road = torch.where(marking[:, None], torch.tensor([0.85, 0.85, 0.8], device=p.device) * (0.9 + 0.1 * grain[:, None]), road)
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
        return colour * (0.5 + 0.9 * fbm(p[:, 0] * 12.0, p[:, 1] * 12.0, p[:, 2] * 12.0, scene.seed + 10, octaves=3))[:, None]
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
        glass = torch.tensor([0.1, 0.14, 0.2], device=device) + 0.45 * torch.tensor([0.9, 0.8, 0.5], device=device) * (lit > 0.8)
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


def _render_chunk(scene: Scene, o: Tensor, d: Tensor) -> tuple[Tensor, Tensor]:
    d = d / torch.sqrt(_dot(d, d))[:, None]
    inf = torch.full(o.shape[:1], math.inf, dtype=o.dtype, device=o.device)
    t_ground = torch.where(d[:, 1] > 1e-9, (scene.camera_height - o[:, 1]) / d[:, 1].clamp_min(1e-9), inf)
    t_box_all, box_axis = _boxes(o, d, scene.box_min, scene.box_max)
    t_cyl_all, cyl_cap = _cylinders(o, d, scene.cyl_centre, scene.cyl_radius, scene.cyl_top, scene.cyl_bottom)
    t_sph_all = _spheres(o, d, scene.sph_centre, scene.sph_radius)
    t_box, i_box = _closest(t_box_all)
    t_cyl, i_cyl = _closest(t_cyl_all)
    t_sph, i_sph = _closest(t_sph_all)
    t_all = torch.stack([t_ground, t_box, t_cyl, t_sph], dim=-1)
    depth, kind = t_all.min(dim=-1)
    p = o + depth.clamp_max(1e6)[:, None] * d

    # Normal, material, colour and texture seed of each hit (ground: material -1), then the
    # textures, each evaluated on its own hits only.
    rows = torch.arange(o.shape[0], device=o.device)
    surfaces = []  # (kind, normal, material, colour, seed) of the closest primitive of each kind
    if scene.box_min.shape[0]:
        axis = box_axis[rows, i_box]
        n_box = torch.zeros_like(d)
        n_box[rows, axis] = -torch.sign(d[rows, axis])
        surfaces.append((1, n_box, scene.box_material[i_box], scene.box_colour[i_box], scene.box_seed[i_box]))
    if scene.cyl_radius.shape[0]:
        radial = p[:, [0, 2]] - scene.cyl_centre[i_cyl]
        radial = radial / torch.sqrt(radial[:, 0] ** 2 + radial[:, 1] ** 2).clamp_min(1e-9)[:, None]
        n_cyl = torch.stack([radial[:, 0], torch.zeros_like(radial[:, 0]), radial[:, 1]], dim=-1)
        n_cyl = torch.where(cyl_cap[rows, i_cyl][:, None], torch.tensor([0.0, -1.0, 0.0], device=o.device), n_cyl)
        surfaces.append((2, n_cyl, scene.cyl_material[i_cyl], scene.cyl_colour[i_cyl], scene.cyl_seed[i_cyl]))
    if scene.sph_radius.shape[0]:
        n_sph = (p - scene.sph_centre[i_sph]) / scene.sph_radius[i_sph][:, None]
        surfaces.append((3, n_sph, scene.sph_material[i_sph], scene.sph_colour[i_sph], scene.sph_seed[i_sph]))
    normal = torch.zeros_like(d)
    normal[:, 1] = -1.0  # ground (and sky, unused)
    material, colour, seed = torch.full_like(kind, -1), torch.zeros_like(d), torch.zeros_like(kind)
    for code, n_k, material_k, colour_k, seed_k in surfaces:
        use = kind == code
        normal = torch.where(use[:, None], n_k, normal)
        material = torch.where(use, material_k, material)
        colour = torch.where(use[:, None], colour_k, colour)
        seed = torch.where(use, seed_k, seed)
    sky = torch.isinf(depth)
    albedo = torch.zeros_like(d)
    ground = (kind == 0) & ~sky
    albedo[ground] = _ground_albedo(scene, p[ground])
    for m in torch.unique(material[~sky & ~ground]).tolist():
        hits = (material == m) & ~sky & ~ground
        albedo[hits] = _surface_albedo(m, colour[hits], seed[hits], p[hits], normal[hits], scene)
    shaded = _shade(scene, albedo, normal)
    shaded[sky] = _sky(scene, d[sky])
    colour = shaded
    if scene.fog_density > 0:
        keep = _exact(torch.exp, -scene.fog_density * depth)[:, None]  # 0 at infinity: the sky is all fog colour...
        keep = torch.where(torch.isinf(depth)[:, None], torch.full_like(keep, 0.6), keep)  # ...but stays visible
        colour = colour * keep + scene.fog_colour * (1 - keep)
    colour = (colour * scene.brightness * scene.white_balance).clamp(0.0, 1.0)
    return colour, depth


def render(scene: Scene, origins: Tensor, directions: Tensor, chunk: int = 1 << 16) -> tuple[Tensor, Tensor]:
    """Colour and depth seen along rays.

    Args:
        origins, directions: ``(..., 3)`` in the scene's frame (see the module docstring); the
            directions need not be unit length. ``origins`` broadcasts against ``directions``.
        chunk: rays per batch; memory grows with ``chunk x primitives``.

    Returns:
        ``rgb`` ``(..., 3)`` in [0, 1] and ``depth`` ``(...)`` in metres along the unit ray, ``inf``
        for the sky. The same bits for any ``chunk`` and any number of torch threads.
    """
    origins, directions = torch.broadcast_tensors(origins, directions)
    shape = directions.shape[:-1]
    o, d = origins.reshape(-1, 3).to(torch.float32), directions.reshape(-1, 3).to(torch.float32)
    scene = scene.to(d.device)
    rgb, depth = [], []
    for start in range(0, o.shape[0], chunk):
        c, t = _render_chunk(scene, o[start:start + chunk], d[start:start + chunk])
        rgb.append(c)
        depth.append(t)
    return torch.cat(rgb).reshape(*shape, 3), torch.cat(depth).reshape(shape)
