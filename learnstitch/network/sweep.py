"""Geometry of the rig-aware warp: a spherical sweep over inverse-depth planes.

The rig's cameras sit at known centres ``c_i`` (world metres, the panorama at the origin), and the
network's inputs are the fisheyes unwarped onto the panorama canvas through the cameras' nominal
orientations (:mod:`learnstitch.data.datasets`). Input ``i`` therefore shows the world direction
``u`` at its canvas point of direction ``u``, up to a small rotation ``R_i`` (the camera's
orientation off its nominal one). A panorama pixel of direction ``w`` whose scene point lies at
inverse depth ``q`` (1 / metres from the centre; 0 at infinity) is seen by input ``i`` along

    v_i = normalize(w - q c_i),        sampled at the canvas point of R_i v_i

so parallax has one degree of freedom per panorama pixel, ``q``, shared by all inputs. The
*sweep* samples every input at a set of inverse-depth planes ``q_1 .. q_P``; where two or more
inputs see a pixel, their disagreement at each plane is a matching cost, lowest at the true
depth. Nothing here assumes three cameras.

Conventions: directions are world vectors (rigjax's frame: x right, y down, z forward); canvas
points are ``grid_sample`` coordinates with ``align_corners=False`` of rigjax's equirectangular
360 x 180 canvas (longitude ``atan2(x, z)``, latitude ``atan2(y, hypot(x, z))``, both ``+`` right
and down), so ``x = lon / pi`` and ``y = lat / (pi / 2)``.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

# The longest run of planes :func:`first_surface` reads: a ray's end marks three, and two inputs'
# ends a plane apart four.
_LONGEST_RUN = 5


def inverse_depth_planes(count: int, max_inverse_depth: float, *, dtype=torch.float32, device=None) -> torch.Tensor:
    """``(count,)`` inverse depths evenly spaced from 0 (infinity) to ``max_inverse_depth``."""
    return torch.linspace(0.0, max_inverse_depth, count, dtype=dtype, device=device)


def towards(rays: torch.Tensor, inverse_depth: torch.Tensor, centres: torch.Tensor) -> torch.Tensor:
    """Unit directions ``normalize(w - q c_i)`` from each centre to the point at inverse depth ``q``:
    unit panorama directions ``rays`` ``(..., 3)``, inverse depths ``(...)`` and ``centres``
    ``(..., 3)``, broadcast together (the caller lays out which axis is the camera's)."""
    v = rays - inverse_depth[..., None] * centres
    return v / v.norm(dim=-1, keepdim=True)


def sweep_points(rays: torch.Tensor, centres: torch.Tensor, planes: torch.Tensor) -> torch.Tensor:
    """The sweep's sampling grids: canvas points of ``w - q c_i`` for panorama rays ``w``
    ``(H, W, 3)``, centres ``c_i`` ``(N, 3)`` and planes ``q`` ``(P,)``: ``(N, P, H, W, 2)``.

    A direction's length does not change its canvas point, so nothing is normalised (``w - q c_i``
    is never zero: ``q |c_i| < 1`` in any rig the sweep covers).
    """
    directions = rays - planes[:, None, None, None] * centres[:, None, None, None, :]
    return canvas_points(directions)


def canvas_points(directions: torch.Tensor) -> torch.Tensor:
    """``(..., 2)`` canvas points (``grid_sample``, ``align_corners=False``) of directions ``(..., 3)``."""
    return component_points(*directions.movedim(-1, 0).contiguous())


def component_points(x: torch.Tensor, y: torch.Tensor, z: torch.Tensor) -> torch.Tensor:
    """The points of directions given by their components ``(...)`` each: longitude over pi,
    latitude over pi / 2, each in [-1, 1] (:func:`canvas_points`; the sight tables' grid reads them
    too, with ``align_corners=True``). Each component contiguous: the transcendental functions
    vectorise over contiguous memory only (over every third number they run several times slower)."""
    lon = torch.atan2(x, z) / math.pi
    lat = torch.atan2(y, torch.hypot(x, z)) * (2.0 / math.pi)
    return torch.stack([lon, lat], dim=-1)


def rotation_matrices(axis_angle: torch.Tensor) -> torch.Tensor:
    """``(..., 3, 3)`` rotations of axis-angle vectors ``(..., 3)`` (radians), Rodrigues' formula."""
    shape = axis_angle.shape[:-1]
    # kornia is imported where it is used: the full-resolution stitch never calls this, and the
    # import is a noticeable share of that command's start-up.
    from kornia.geometry.conversions import axis_angle_to_rotation_matrix

    return axis_angle_to_rotation_matrix(axis_angle.reshape(-1, 3)).reshape(*shape, 3, 3)


def rotate(rotations: torch.Tensor, directions: torch.Tensor) -> torch.Tensor:
    """``R_i v`` for rotations ``(B, N, 3, 3)`` and directions ``(N, ..., 3)`` or ``(B, N, ..., 3)``:
    ``(B, N, ..., 3)``."""
    batch, n = rotations.shape[:2]
    if directions.shape[:2] != (batch, n):
        directions = directions.expand(batch, *directions.shape)
    flat = directions.reshape(batch, n, -1, 3)
    return torch.einsum("bnij,bnpj->bnpi", rotations, flat).reshape(directions.shape)


def matching_cost(samples: torch.Tensor, alpha: torch.Tensor, window: int = 5) -> tuple[torch.Tensor, torch.Tensor]:
    """Disagreement of the inputs at each plane: ``(B, P, H, W)`` cost and overlap.

    ``samples`` ``(B, N, C, P, H, W)``: the inputs swept to each plane (zero outside their masks,
    as the inputs are); ``alpha`` ``(B, N, P, H, W)``: the swept masks. An input takes part in a
    pixel where its swept mask is whole (``alpha > 0.999``: bilinear samples off the mask's edge).
    The cost is the variance of the taking-part inputs, summed over the channels, where at least
    two take part, averaged over a ``window`` x ``window`` box around the pixel (over the
    overlapping pixels of the box); the overlap is 1 where two or more take part, else 0 (and the
    cost 0).
    """
    part = (alpha > 0.999).to(samples.dtype)
    count = part.sum(dim=1)  # (B, P, H, W)
    overlap = (count >= 2).to(samples.dtype)
    x = samples * part[:, :, None]
    inverse = overlap / count.clamp_min(1.0)
    mean = x.sum(dim=1) * inverse[:, None]  # (B, C, P, H, W)
    variance = ((x * x).sum(dim=1) * inverse[:, None] - mean * mean).clamp_min(0.0).sum(dim=1)
    if window > 1:
        pooled = [_box(t, window) for t in (variance, overlap)]
        variance = pooled[0] / pooled[1].clamp_min(1e-6) * overlap
    return variance, overlap


def _box(x: torch.Tensor, window: int) -> torch.Tensor:
    """The mean of ``x`` ``(..., H, W)`` over a ``window`` x ``window`` box around each pixel (zeros
    outside): sums of shifted copies, one axis at a time (``avg_pool2d``'s result, in fewer
    operations)."""
    height, width = x.shape[-2:]
    pad = window // 2
    padded = F.pad(x, (pad, pad, pad, pad))
    rows = sum(padded[..., i : i + height, :] for i in range(window))
    return sum(rows[..., j : j + width] for j in range(window)) / (window * window)


def ghost_cost(far_cost: torch.Tensor, alpha: torch.Tensor) -> torch.Tensor:
    """Where a plane's point lies in each input, the cost of the plane at infinity there:
    ``(B, P, H, W)``, the mean over the inputs that take part (as in :func:`matching_cost`; 0
    where none does).

    ``far_cost`` ``(B, N, P, H, W)``: the cost at infinity (a panorama map) sampled through the
    sweep's grids, so that ``[b, i, p]`` is its value where input ``i`` sees plane ``p``'s point of
    each panorama ray; ``alpha`` ``(B, N, P, H, W)``: the swept masks. A thin near occluder in
    front of a far background matches at its own plane *and* at infinity (both inputs see past it
    to the same background), but only at its own plane does each input's view of the point lie
    where the inputs disagree at infinity: on the occluder's ghosts. It marks an occluder against a
    background of another colour, not near surfaces in general: a false near minimum's views may
    land on any disagreement at infinity.
    """
    part = (alpha > 0.999).to(far_cost.dtype)
    return (far_cost * part).sum(dim=1) / part.sum(dim=1).clamp_min(1.0)


def ray_points(rays: torch.Tensor, centres: torch.Tensor, planes: torch.Tensor) -> torch.Tensor:
    """The sweep's inverse: ``(N, P, H, W, 2)`` canvas points of the panorama direction of the point
    at inverse depth ``q`` (``1 / |X|``, from the panorama's centre) on input ``i``'s own ray along
    each canvas direction ``v`` (``rays`` ``(H, W, 3)``, unit), for centres ``c_i`` ``(N, 3)`` and
    planes ``(P,)``.

    The point is ``X = c_i + t v`` with ``|X| = 1 / q``, so ``q X = q c_i + s v`` with
    ``s = sqrt(1 - q^2 (|c_i|^2 - (c_i . v)^2)) - q (c_i . v)`` (``q |c_i| < 1``: the camera is
    inside the plane's sphere, and every ray leaves it once); at ``q = 0`` it is ``v`` itself.
    """
    c = centres[:, None, None, None, :]
    q = planes[None, :, None, None, None]
    along = (c * rays).sum(dim=-1, keepdim=True)
    reach = (1.0 - q * q * ((c * c).sum(dim=-1, keepdim=True) - along * along)).clamp_min(0.0)
    return canvas_points(q * c + (reach.sqrt() - q * along) * rays)


def ray_ends(cost: torch.Tensor, overlap: torch.Tensor, threshold: float = 0.5, margin: float = 1.5) -> torch.Tensor:
    """Where each input's own rays end: ``(B, N, P, H, W)`` bool, true at the planes within one of
    a ray's clear cost minimum.

    ``cost`` ``(B, N, P, H, W)``: the matching cost of each plane's point on input ``i``'s ray
    through each canvas point (the panorama's cost volume read through :func:`ray_points`);
    ``overlap`` (bool, same shape): where two or more inputs see that point and ``i`` sees along its
    ray. Along a ray the cost is taken relative to its mean over the overlapping planes; a minimum
    is clear when it is below ``threshold`` and every plane three or more away costs over ``margin``
    times as much. A ray through a thin near pole ends there: its points beyond the pole lie on the
    pole's ghosts, where the inputs disagree, whereas along the panorama's own ray through the pole
    both cameras see past it to the same background and two planes match.
    """
    planes = cost.shape[2]
    mean = (cost * overlap).sum(dim=2, keepdim=True) / overlap.sum(dim=2, keepdim=True).clamp_min(1)
    relative = torch.where(overlap, cost / (mean + 1e-6), torch.inf)
    least, best = relative.min(dim=2, keepdim=True)
    offset = (torch.arange(planes, device=cost.device)[:, None, None] - best).abs()
    others = torch.where(offset >= 3, relative, torch.inf).amin(dim=2, keepdim=True)
    clear = (least < threshold) & (others > margin * least)
    return (offset <= 1) & clear


def first_surface(evidence: torch.Tensor) -> torch.Tensor:
    """``(B, P, H, W)`` one-hot of the first surface from the panorama's centre, which hides those
    behind it: the nearest run of planes where ``evidence`` ``(B, P, H, W)`` (bool,
    :func:`ray_ends` read back along the panorama's rays) holds, at its middle (a ray's end marks its
    minimum and the planes either side; an even run's middle is taken on its far side); zero where
    it holds at no plane."""
    planes = evidence.shape[1]
    index = torch.arange(planes, device=evidence.device)[:, None, None]
    nearest = torch.where(evidence, index, -1).amax(dim=1, keepdim=True)
    run = torch.zeros_like(nearest)
    held = nearest >= 0
    for k in range(_LONGEST_RUN):
        held = held & evidence.gather(1, (nearest - k).clamp_min(0)) & (nearest - k >= 0)
        run = run + held.to(run.dtype)
    return ((index == nearest - run // 2) & (run > 0)).to(torch.float32)


def surface_planes(first: torch.Tensor) -> torch.Tensor:
    """``(B, H, W)`` the plane index of a one-hot :func:`first_surface` ``(B, P, H, W)``; -1 where it
    has none."""
    return torch.where(first.amax(dim=1) > 0, first.argmax(dim=1), -1)


def supported_planes(planes: torch.Tensor, count: int, need: int, radius: int = 2) -> torch.Tensor:
    """``planes`` ``(B, H, W)`` (plane indices below ``count``, -1 for none) kept where at least
    ``need`` others lie in the ``(2 radius + 1)``-square box around them at a plane within one of
    theirs (the box wraps around the panorama's +-180 degree edge, not its poles); -1 elsewhere. A
    surface is a patch at one depth; a false match is mostly a speck."""
    present = planes >= 0
    onehot = torch.zeros(planes.shape[0], count, *planes.shape[1:], device=planes.device)
    onehot.scatter_(1, planes.clamp_min(0)[:, None], present[:, None].to(onehot.dtype))
    nearby = F.max_pool3d(onehot[:, None], (3, 1, 1), 1, (1, 0, 0))[:, 0]  # at its plane or one either side
    side = 2 * radius + 1
    padded = F.pad(F.pad(nearby, (radius, radius, 0, 0), mode="circular"), (0, 0, radius, radius))
    others = F.avg_pool2d(padded, side, 1) * side * side - 1.0
    return torch.where(present & (others.gather(1, planes.clamp_min(0)[:, None])[:, 0] >= need - 0.5), planes, -1)


def grown_planes(seeds: torch.Tensor, candidates: torch.Tensor, steps: int) -> torch.Tensor:
    """``seeds`` ``(B, H, W)`` (plane indices, -1 for none) grown into ``candidates`` (the same) by
    hysteresis, as an edge detector joins weak edges to strong ones: a pixel without a seed takes
    its candidate's plane where a 4-neighbour holds a plane within one of it, ``steps`` pixels
    out at most (wrapping around the panorama's +-180 degree edge, not its poles)."""
    held = seeds.clone()
    for _ in range(steps):
        joined = torch.zeros_like(held, dtype=torch.bool)
        for shift, dim in ((1, 2), (-1, 2), (1, 1), (-1, 1)):
            neighbour = torch.roll(held, shift, dim)
            if dim == 1:  # rows do not wrap
                neighbour[:, 0 if shift == 1 else -1] = -1
            joined |= (neighbour >= 0) & ((candidates - neighbour).abs() <= 1)
        taken = joined & (held < 0) & (candidates >= 0)
        if not taken.any():
            break
        held = torch.where(taken, candidates, held)
    return held


def plane_colours(samples: torch.Tensor, alpha: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """What the inputs show at each plane: their mean ``(B, C, P, H, W)`` over the inputs that take
    part (as in :func:`matching_cost`), and ``(B, P, H, W)`` 1 where at least one takes part, else 0
    (and the mean 0). ``samples`` ``(B, N, C, P, H, W)`` and ``alpha`` ``(B, N, P, H, W)`` as there."""
    part = (alpha > 0.999).to(samples.dtype)
    count = part.sum(dim=1)
    seen = (count >= 1).to(samples.dtype)
    return (samples * part[:, :, None]).sum(dim=1) * (seen / count.clamp_min(1.0))[:, None], seen


def soft_argmin(cost: torch.Tensor, planes: torch.Tensor, dim: int = 1) -> torch.Tensor:
    """The expected plane under ``softmax(-cost)`` along ``dim``: a differentiable argmin."""
    shape = [1] * cost.ndim
    shape[dim] = -1
    return (torch.softmax(-cost, dim=dim) * planes.reshape(shape)).sum(dim=dim)
