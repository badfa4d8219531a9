"""The rig-aware warp (model.warp: depth), the sight lines and the depth oracle against rigjax's own
projections, closed forms and the renderer."""

from __future__ import annotations

import dataclasses
import json
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import torch
import torch.nn.functional as F
from torch import nn

import rigjax
from learnstitch.baselines import depth_oracle_stitch, psnr, rotation_only_stitch
from learnstitch.checkpoint import CHECKPOINT_FORMAT, save_checkpoint
from learnstitch.config import StitchConfig, config_as_dict, config_from_dict
from learnstitch.data.datasets import FolderDataset, GeneratedDataset
from learnstitch.data.generate import synthesise
from learnstitch.data.rig import (
    feather_weights,
    nominal_cameras,
    nominal_centres,
    pano_rays,
    sample_rig,
    unwarp_grids,
)
from learnstitch.data.sample import Sample, SynthConfig, make_sample, nominal_unwarp_grids, unwarp
from learnstitch.data.scene import render, sample_scene
from learnstitch.data.visibility import sight_lines
from learnstitch.inference import stitch_fisheyes
from learnstitch.network import build_model
from learnstitch.network.depth import _FILL_FLOOR, DepthStitchNet, smooth_fill
from learnstitch.network.losses import LossConfig, StitchLoss, plane_class_loss, plane_loss, surface_loss
from learnstitch.network.model import ModelConfig
from learnstitch.network.sweep import (
    canvas_points,
    first_surface,
    grown_planes,
    inverse_depth_planes,
    matching_cost,
    plane_colours,
    ray_ends,
    ray_points,
    rotate,
    rotation_matrices,
    soft_argmin,
    supported_planes,
    surface_planes,
    sweep_points,
    towards,
)
from learnstitch.training import _initialise_from, train
from rigjax.errors import ConfigError

DEPTH_VALUES = {"warp": "depth", "widths": [4, 8, 8], "regressor_width": 8, "head_width": 4, "depth_planes": 8}
DEPTH = ModelConfig(**{**DEPTH_VALUES, "widths": (4, 8, 8)})
# No jitter and clean photometry: the nominal rig is the true one.
EXACT = SynthConfig(
    fisheye_size=64,
    pano_width=128,
    distance=0.4,
    angle_jitter_deg=0.0,
    hfov_jitter_deg=0.0,
    gain_jitter=0.0,
    vignetting=0.0,
    noise_std=0.0,
)


def _rigjax_canvas_point(direction: np.ndarray, width: int, height: int) -> np.ndarray:
    """``grid_sample`` coordinates of a direction on rigjax's equirectangular canvas."""
    with jax.enable_x64(True):
        xy = np.asarray(rigjax.ray_to_pano(rigjax.Equirect.create(width, height, 360.0), jnp.asarray(direction)))
    return (xy + 0.5) / np.array([width, height]) * 2.0 - 1.0


def test_a_world_point_lands_through_the_sweep_where_rigjax_projects_it_in_every_input():
    width, height, planes = 64, 32, inverse_depth_planes(6, 1.0, dtype=torch.float64)
    rays = torch.as_tensor(pano_rays(width, height))
    centres = torch.as_tensor(nominal_centres(0.4))
    grids = sweep_points(rays, centres, planes)  # (3, P, H, W, 2)
    cameras = nominal_cameras(64, 185.0)
    for x, y, j in [(5, 20, 1), (21, 17, 3), (33, 25, 5), (50, 9, 2), (62, 16, 4)]:
        point = rays[y, x].numpy() / planes[j].item()  # at the plane's inverse depth
        for i in range(3):
            toward = point - centres[i].numpy()
            expected = _rigjax_canvas_point(toward, width, height)
            np.testing.assert_allclose(grids[i, j, y, x].numpy(), expected, atol=1e-9)
            # The unwarped input at that canvas point is the fisheye where rigjax images the point.
            with jax.enable_x64(True):
                camera = jax.tree_util.tree_map(lambda v, i=i: jnp.asarray(v[i]), cameras)
                canvas = rigjax.Equirect.create(width, height, 360.0)
                ray = rigjax.pano_to_ray(
                    canvas, jnp.asarray((grids[i, j, y, x].numpy() + 1.0) / 2.0 * [width, height] - 0.5)
                )
                through_sweep, ok = rigjax.ray_to_img(camera, ray)
                direct, _ = rigjax.ray_to_img(camera, jnp.asarray(toward))
            assert bool(ok)
            np.testing.assert_allclose(np.asarray(through_sweep), np.asarray(direct), atol=1e-6)
    # Plane 0 is infinity: every input samples each pixel where it is.
    identity = torch.stack(
        torch.meshgrid(
            (torch.arange(width) + 0.5) / width * 2 - 1, (torch.arange(height) + 0.5) / height * 2 - 1, indexing="xy"
        ),
        -1,
    )
    torch.testing.assert_close(grids[:, 0], identity.to(grids).expand(3, height, width, 2), atol=1e-12, rtol=0)


def test_a_residual_rotation_turns_the_sampled_directions():
    angles = torch.tensor([[[0.0, math.radians(3.0), 0.0], [0.01, -0.02, 0.03], [0.0, 0.0, 0.0]]], dtype=torch.float64)
    rotations = rotation_matrices(angles)
    # A turn about y (down) by 3 degrees moves a horizon direction's longitude by 3 degrees.
    horizon = torch.tensor([[math.sin(0.2), 0.0, math.cos(0.2)]], dtype=torch.float64).expand(3, 1, 3)
    turned = canvas_points(rotate(rotations, horizon))
    assert turned[0, 0, 0, 0].item() == pytest.approx((0.2 + math.radians(3.0)) / math.pi, abs=1e-12)
    # Rotations are orthonormal with determinant 1, and zero angles give the identity.
    torch.testing.assert_close(
        rotations @ rotations.transpose(-1, -2), torch.eye(3, dtype=torch.float64).expand_as(rotations)
    )
    assert torch.det(rotations).sub(1).abs().max() < 1e-12 and torch.equal(
        rotations[0, 2], torch.eye(3, dtype=torch.float64)
    )


def test_the_sweep_samples_each_turned_input_where_its_rotation_and_the_plane_point():
    # The network sweeps each input turned by its residual rotation (resampled at infinity) through
    # grids fixed per rig: input i at plane q must show the canvas at R_i normalize(w - q c_i).
    # The inputs are a smooth function of the direction, so the expected value is in closed form.
    height, width = 64, 128
    model = DepthStitchNet(dataclasses.replace(DEPTH, depth_planes=5), nominal_centres(0.4)).double()
    rays = torch.as_tensor(pano_rays(width, height))

    def shade(d):
        return 0.5 + 0.25 * d[..., 0] + 0.15 * d[..., 1] - 0.1 * d[..., 2] + 0.1 * d[..., 0] * d[..., 2]

    canvas = torch.stack([shade(rays), torch.ones(height, width, dtype=torch.float64)])  # colour, mask
    x = torch.cat([canvas[:1].expand(3, -1, -1), canvas[1:]])[None, None].expand(2, 3, 4, height, width)
    angles = torch.tensor([[0.0, 3.0, 0.0], [1.0, -2.0, 2.5], [-2.0, 0.5, 0.0]], dtype=torch.float64)
    rotations = rotation_matrices(torch.deg2rad(torch.stack([angles, -angles])))  # (2, 3, 3, 3)
    turned = model.warp(x, torch.zeros(2, height, width, dtype=torch.float64), rotations)
    swept = model.sweep(turned, model.sweep_grid(height, width))  # (2, 3, 4, P, H, W)
    swept, alpha = swept[:, :, :3], swept[:, :, 3]
    along = towards(
        rays, model.planes[:, None, None].double(), model.centres.double()[:, None, None, None]
    )  # (3, P, H, W, 3)
    point = rotate(rotations, along)
    expected = shade(point)  # (2, 3, P, H, W)
    # Away from the canvas's top and bottom rows, where bilinear samples read the zeros beyond it.
    polar = math.sin(math.radians(70.0))
    inside = (along[..., 1].abs() < polar) & (point[..., 1].abs() < polar)
    error = (swept[:, :, 0] - expected).abs()[inside]
    assert error.max() < 2e-3, error.max()
    assert (alpha[inside] > 0.999).all()
    # Without the turn the same samples are off by the rotation: the test can tell.
    unturned = model.sweep(x, model.sweep_grid(height, width))[:, :, :3]
    assert (unturned[:, :, 0] - expected).abs()[inside].max() > 5e-3


@pytest.mark.parametrize("minimum", [0, 3, 7])
def test_soft_argmin_of_a_cost_volume_with_one_clear_minimum_returns_that_depth(minimum):
    planes = inverse_depth_planes(8, 1.0, dtype=torch.float64)
    cost = 50.0 * (torch.arange(8, dtype=torch.float64) - minimum) ** 2
    volume = cost[None, :, None, None].expand(2, 8, 3, 4)
    torch.testing.assert_close(
        soft_argmin(volume, planes), torch.full((2, 3, 4), planes[minimum].item(), dtype=torch.float64)
    )
    # A minimum between two planes, symmetric about it: the soft-argmin interpolates it.
    between = (planes[3] + planes[4]) / 2
    wide = 200.0 * (planes - between) ** 2
    assert soft_argmin(wide[None, :, None, None], planes).item() == pytest.approx(between.item(), abs=1e-9)


def test_the_matching_cost_is_the_variance_of_the_inputs_that_see_a_pixel():
    g = torch.Generator().manual_seed(0)
    samples = torch.rand(1, 3, 3, 2, 4, 5, generator=g, dtype=torch.float64)
    alpha = torch.ones(1, 3, 2, 4, 5, dtype=torch.float64)
    alpha[0, 2, 1] = 0.0  # input 2 does not see plane 1
    alpha[0, 1, 1, 0, 0] = 0.0  # nor input 1 pixel (0, 0) of plane 1: one input left there
    samples = samples * alpha[:, :, None]
    cost, overlap = matching_cost(samples, alpha, window=1)
    expected0 = samples[0, :, :, 0].var(dim=0, unbiased=False).sum(dim=0)
    expected1 = samples[0, :2, :, 1].var(dim=0, unbiased=False).sum(dim=0)
    expected1[0, 0] = 0.0
    torch.testing.assert_close(cost[0, 0], expected0)
    torch.testing.assert_close(cost[0, 1], expected1)
    assert overlap[0, 1, 0, 0] == 0 and overlap.sum() == 2 * 4 * 5 - 1


def _pole_scene(height: int = 64, width: int = 128) -> tuple[torch.Tensor, torch.Tensor]:
    """A pole 1 m from the centre (radius 0.1 m) in the seam between cameras 0 and 1 of the nominal
    d = 0.4 m rig, in front of a smooth background at infinity: each input ray cast in closed form
    (vertical cylinder), 185-degree lenses. The inputs with their masks ``(1, 3, 4, H, W)`` (float64)
    and the centres ``(3, 3)``. The pole's direction is column 85 (yaw 60.5 degrees)."""
    centres = torch.as_tensor(nominal_centres(0.4))
    rays = torch.as_tensor(pano_rays(width, height))
    axis, radius = torch.tensor([math.sin(math.radians(60.0)), math.cos(math.radians(60.0))]), 0.1

    def view(centre):
        o, u = centre[[0, 2]] - axis, rays[..., [0, 2]]
        a, b, c = (u * u).sum(-1), 2.0 * (u * o).sum(-1), (o * o).sum() - radius**2
        disc = b * b - 4.0 * a * c
        hit = (disc >= 0) & ((-b - disc.clamp_min(0.0).sqrt()) > 0)
        background = (
            0.6 + 0.2 * rays[..., 0] + 0.15 * rays[..., 1] - 0.1 * rays[..., 2] + 0.1 * rays[..., 0] * rays[..., 2]
        )
        return torch.where(hit, 0.1, background)

    yaws = torch.deg2rad(torch.tensor([0.0, 120.0, 240.0], dtype=torch.float64))
    facing = rays[None, ..., 0] * torch.sin(yaws)[:, None, None] + rays[None, ..., 2] * torch.cos(yaws)[:, None, None]
    masks = (facing >= math.cos(math.radians(92.5))).double()
    inputs = torch.stack([view(c) for c in centres])[:, None].expand(3, 3, height, width)
    return torch.cat([inputs, masks[:, None]], dim=1)[None], centres


def test_a_thin_near_pole_matches_at_infinity_too_and_only_its_own_planes_read_its_ghosts():
    # Along the pole's direction both cameras see past it to the same background, so the matching
    # cost has a minimum at infinity as well as at the pole's planes; the ghost cost (the cost at
    # infinity where each input sees a plane's point) tells them apart.
    x, centres = _pole_scene()
    height, width = x.shape[-2:]
    config = dataclasses.replace(DEPTH, depth_planes=8, max_inverse_depth=1.4, ghost_cost=True)
    model = DepthStitchNet(config, centres).double()
    identity = torch.eye(3, dtype=torch.float64).expand(1, 3, 3, 3)
    far = model.warp(x, torch.zeros(1, height, width, dtype=torch.float64), identity)
    swept = model.sweep(far, model.sweep_grid(height, width))
    cost, overlap = matching_cost(swept[:, :, :3], swept[:, :, 3], 5)
    ghosts = model.ghosts(cost, overlap, swept[:, :, 3])[0]
    row, column = height // 2, 85  # the pole's direction (yaw 60.5 degrees)
    pole = [5, 6]  # planes 1.0 and 1.2 per metre: its axis and in front of its surface (1.11)
    at = cost[0, :, row, column]
    assert at[0] < 0.01 * at.max() and (at[pole] < 0.1 * at.max()).all(), at  # two minima
    assert ghosts[0, row, column] < 0.1 and (ghosts[pole, row, column] > math.log(5.0)).all(), ghosts[:, row, column]
    assert ghosts[:, row, width - 1].max() < 0.1  # yaw 178.6 degrees: no occluder, no ghosts
    # The extra channels the decoder reads: the relative cost, the overlap and the ghosts.
    assert model.decoder.merge[0][0].in_channels == 8 + 8 * 3 + 2 * 8 + 1
    with pytest.raises(ConfigError, match="ghost_cost: true needs warp: depth"):
        config_from_dict({"model": {"ghost_cost": True}}, "h.yaml")


def test_ray_points_find_each_planes_point_on_an_inputs_own_ray():
    # Reference: the positive root of |c + t v|^2 = 1 / q^2 (numpy's polynomial roots), projected
    # by rigjax; at q = 0 the ray's own direction.
    rng = np.random.default_rng(3)
    centres = rng.normal(size=(3, 3))
    centres *= np.array([[0.1], [0.3], [0.5]]) / np.linalg.norm(centres, axis=1, keepdims=True)  # q |c| < 1
    rays = rng.normal(size=(1, 7, 3))
    rays /= np.linalg.norm(rays, axis=-1, keepdims=True)
    planes = torch.tensor([0.0, 0.4, 1.1, 1.8], dtype=torch.float64)
    got = ray_points(torch.as_tensor(rays), torch.as_tensor(centres), planes).numpy()  # (3, 4, 1, 7, 2)
    for i, c in enumerate(centres):
        for p, q in enumerate(planes.tolist()):
            for k, v in enumerate(rays[0]):
                if q == 0.0:
                    point = v
                else:
                    t = max(np.roots([1.0, 2.0 * c @ v, c @ c - 1.0 / q**2]).real)
                    point = c + t * v
                    assert abs(np.linalg.norm(point) - 1.0 / q) < 1e-9
                np.testing.assert_allclose(got[i, p, 0, k], _rigjax_canvas_point(point, 360, 180), atol=1e-9)


def test_a_ray_ends_at_its_clear_cost_minimum_and_nowhere_else():
    planes = 12
    cost = torch.ones(1, 1, planes, 1, 6)
    overlap = torch.ones(1, 1, planes, 1, 6, dtype=torch.bool)
    cost[..., 7, 0, 0] = 0.1  # one clear minimum
    cost[..., [2, 9], 0, 1] = 0.1  # two as good, apart: which is the end?
    cost[..., 5, 0, 2] = 0.6  # a minimum, not clear: 0.62 of the ray's mean
    cost[..., 4, 0, 3] = 0.05  # a minimum where fewer than two inputs see the point
    overlap[..., 4, 0, 3] = False
    cost[..., 3, 0, 4], cost[..., 4, 0, 4] = 0.1, 0.12  # a minimum two planes wide
    overlap[..., :, 0, 5] = False  # no plane seen twice
    ends = ray_ends(cost, overlap)[0, 0, :, 0]  # (planes, rays)
    expected = torch.zeros(planes, 6, dtype=torch.bool)
    expected[6:9, 0] = True
    expected[2:5, 4] = True
    assert torch.equal(ends, expected), ends.nonzero()


def test_the_first_surface_is_the_middle_of_the_nearest_run_of_planes_where_rays_end():
    evidence = torch.zeros(1, 8, 1, 5, dtype=torch.bool)
    evidence[0, [0, 1, 5, 6, 7], 0, 0] = True  # runs 0-1 and 5-7: the nearer one's middle, 6
    evidence[0, [0, 1], 0, 2] = True  # a ray ending at infinity (no plane beyond it): 0
    evidence[0, [2, 4], 0, 3] = True  # two runs of one: the nearer, 4
    evidence[0, 2:6, 0, 4] = True  # an even run: its middle's far side, 3
    first = first_surface(evidence)[0, :, 0]
    assert torch.equal(first.argmax(dim=0), torch.tensor([6, 0, 0, 4, 3]))
    assert torch.equal(first.sum(dim=0), torch.tensor([1.0, 0.0, 1.0, 1.0, 1.0]))


def test_supported_planes_keep_a_surface_and_drop_specks_as_a_brute_force_count_does():
    # Reference: for each pixel, count by hand the others in its 5 x 5 box (columns wrapping round
    # the +-180 degree edge, rows not) whose plane is within one of its own.
    rng = np.random.default_rng(5)
    planes = np.where(rng.random((2, 9, 12)) < 0.45, rng.integers(0, 6, size=(2, 9, 12)), -1)
    planes[0, 2:7, 3:8] = 4  # a patch at one depth, which survives any speck around it
    planes[1, 3:6, [0, 1, 11]] = 2  # a patch across the +-180 degree edge
    got = supported_planes(torch.as_tensor(planes), 6, need=6).numpy()
    expected = np.full_like(planes, -1)
    batch, height, width = planes.shape
    for b in range(batch):
        for y in range(height):
            for x in range(width):
                if planes[b, y, x] < 0:
                    continue
                others = (
                    sum(
                        abs(planes[b, yy, xx % width] - planes[b, y, x]) <= 1 and planes[b, yy, xx % width] >= 0
                        for yy in range(max(y - 2, 0), min(y + 3, height))
                        for xx in range(x - 2, x + 3)
                    )
                    - 1
                )
                expected[b, y, x] = planes[b, y, x] if others >= 6 else -1
    np.testing.assert_array_equal(got, expected)
    assert (got[0, 3:6, 4:7] == 4).all() and (got[1, 3:6, [0, 11]] == 2).all()


def test_grown_planes_join_candidates_to_seeds_by_hysteresis():
    none = -1
    seeds = torch.full((1, 5, 8), none)
    candidates = torch.full((1, 5, 8), none)
    seeds[0, 2, 1] = 5
    candidates[0, 2, 2:7] = torch.tensor([5, 6, 7, 7, 9])  # a run rising a plane a pixel, then a jump of two
    candidates[0, 2, 0] = 4  # the seed's other side, then round the +-180 degree edge
    candidates[0, 2, 7] = 4
    candidates[0, 4, 1] = 5  # not joined: two rows below the seed with nothing between
    candidates[0, 0, 1] = 5  # joined through nothing either
    candidates[0, 1, 1] = 8  # above the seed, three planes off: not joined
    grown = grown_planes(seeds, candidates, steps=8)[0]
    expected = torch.full((5, 8), none)
    expected[2, :6] = torch.tensor([4, 5, 5, 6, 7, 7])
    expected[2, 7] = 4  # across the edge, from column 0
    assert torch.equal(grown, expected), grown
    two = grown_planes(seeds, candidates, steps=2)[0]  # two pixels out at most
    assert torch.equal(two[2], torch.tensor([4, 5, 5, 6, none, none, none, 4]))
    assert torch.equal(grown_planes(seeds, candidates, steps=0), seeds)
    # surface_planes reads a one-hot's plane, -1 where it holds none.
    first = torch.zeros(1, 4, 1, 2)
    first[0, 3, 0, 0] = 1.0
    assert torch.equal(surface_planes(first), torch.tensor([[[3, none]]]))


def test_a_thin_near_pole_is_the_first_surface_though_the_cost_matches_at_infinity_too():
    # Along the pole's direction the panorama's cost has two minima (the test above); along each
    # camera's own ray towards the pole it has one, at the pole, since beyond the pole that ray's
    # points lie on the pole's ghosts. The first surface along the pole's direction is therefore the
    # pole's plane, and where nothing stands nearer it is infinity.
    x, centres = _pole_scene()
    height, width = x.shape[-2:]
    config = dataclasses.replace(DEPTH, depth_planes=8, max_inverse_depth=1.4, first_surface=True)
    model = DepthStitchNet(config, centres).double()
    far = model.warp(x, torch.zeros(1, height, width, dtype=torch.float64), None)
    grid = model.sweep_grid(height, width)
    swept = model.sweep(far, grid)
    cost, overlap = matching_cost(swept[:, :, :3], swept[:, :, 3], 5)
    views = model.surface_views(cost, overlap, swept[:, :, 3], x[:, :, 3], grid, model.ray_grid(height, width))
    evidence = views[0] >= 2  # two inputs' rays end there
    first = first_surface(evidence[None])[0].argmax(dim=0)
    row, column = height // 2, 85
    assert evidence[0, row, column] and first[row, column] in (5, 6), evidence[:, row, column]  # pole: 1.0-1.11 1/m
    assert first[row, width - 1] == 0 and not evidence[2:, row, width - 1].any()  # yaw 178.6: the background
    # The network: all of a pixel's probability moved to its first surface reads the pole's depth there.
    nn.init.constant_(model.surface_head.bias, 60.0)
    model.float()  # float32 (the rotations' regressor is): its grids are made again in that dtype
    out = model(x[:, :, :3].float(), x[:, :, 3].float(), centres=torch.as_tensor(centres).float()[None])
    assert abs(float(out.inverse_depth[0, row, column]) - float(model.planes[first[row, column]])) < 1e-6
    assert model.decoder.merge[0][0].in_channels == 8 + 8 * 3 + 8 + 1 + 2 * 8  # cost, overlap, evidence, first
    with pytest.raises(ConfigError, match="first_surface: true needs warp: depth"):
        config_from_dict({"model": {"first_surface": True}}, "h.yaml")


def test_the_surface_rule_puts_the_pole_at_its_plane_at_inference_only():
    # The untrained network takes the cost's minimum, which along the pole's direction is infinity
    # too; the rule replaces the depth by the first surface where it is over two planes nearer.
    x, centres = _pole_scene()
    x = x.float()
    height, width = x.shape[-2:]
    base = dataclasses.replace(DEPTH, depth_planes=8, max_inverse_depth=1.4)
    torch.manual_seed(0)
    plain = DepthStitchNet(base, centres).eval()
    ruled = DepthStitchNet(dataclasses.replace(base, surface_rule=2.0), centres).eval()
    ruled.load_state_dict(plain.state_dict())
    with torch.no_grad():
        before = plain(x[:, :, :3], x[:, :, 3]).inverse_depth[0]
        after = ruled(x[:, :, :3], x[:, :, 3]).inverse_depth[0]
        oracle = ruled(x[:, :, :3], x[:, :, 3], inverse_depth=before[None]).inverse_depth[0]
        training = ruled.train()(x[:, :, :3], x[:, :, 3]).inverse_depth[0]
    row, column = height // 2, 85
    assert float(before[row, column]) < 0.4
    assert min(abs(float(after[row, column]) - q) for q in (1.0, 1.2)) < 1e-6  # planes 5 and 6
    assert torch.equal(after[:, width - 1], before[:, width - 1])  # the background: no nearer surface
    assert torch.equal(oracle, before) and torch.equal(training, before)  # a given depth, and training: as is
    with pytest.raises(ConfigError, match="surface_rule must be >= 0"):
        config_from_dict({"model": {"warp": "depth", "surface_rule": -1}}, "h.yaml")
    # Grown: the rule's surface, less specks, plus where one input's ray ends beside it. Reference:
    # the pole's inverse depth along each panorama ray in closed form (the ray's distance to the axis).
    grown = DepthStitchNet(dataclasses.replace(base, surface_rule=2.0, surface_grow=8), centres).eval()
    grown.load_state_dict(plain.state_dict())
    with torch.no_grad():
        wider = grown(x[:, :, :3], x[:, :, 3]).inverse_depth[0]
    rays = torch.as_tensor(pano_rays(width, height))
    u, o = rays[..., [0, 2]], -torch.tensor([math.sin(math.radians(60.0)), math.cos(math.radians(60.0))])
    a, b, c = (u * u).sum(-1), 2.0 * (u * o).sum(-1), (o * o).sum() - 0.1**2
    reach = ((-b - (b * b - 4.0 * a * c).clamp_min(0.0).sqrt()) / (2.0 * a)).float()  # metres along the ray
    pole = (b * b - 4.0 * a * c >= 0) & (reach > 0)
    at_pole = [int((((depth - 1.0 / reach).abs() <= 0.2) & pole).sum()) for depth in (wider, after, before)]
    assert at_pole[0] > 1.3 * at_pole[1] > 1.3 * at_pole[2], at_pole  # grown, the rule alone, plain
    moved = torch.nonzero(wider != before)[:, 1]
    edges = torch.nonzero(pole.any(dim=0))[:, 0]
    assert moved.min() >= edges.min() - 2 and moved.max() <= edges.max() + 2  # beside the pole: two pixels at most
    assert torch.equal(wider[:, width - 1], before[:, width - 1])
    for bad, message in (
        (-1, "surface_grow must be an integer >= 0"),
        (1.5, "model.surface_grow: expected an integer"),
    ):
        with pytest.raises(ConfigError, match=message):
            config_from_dict({"model": {"warp": "depth", "surface_rule": 2, "surface_grow": bad}}, "h.yaml")
    with pytest.raises(ConfigError, match="surface_grow > 0 needs surface_rule > 0"):
        config_from_dict({"model": {"warp": "depth", "surface_grow": 4}}, "h.yaml")


def test_a_run_with_a_new_cue_starts_as_the_checkpoint_without_it(tmp_path):
    # The decoder's convolutions read the cue's channels last: widened with zeros, and with the first
    # surface's share at zero, the network is the checkpoint's function.
    torch.manual_seed(2)
    donor = DepthStitchNet(DEPTH, nominal_centres(0.4))
    path = tmp_path / "donor.pt"
    state = {
        "format": CHECKPOINT_FORMAT,
        "config": config_as_dict(StitchConfig(model=DEPTH)),
        "model": donor.state_dict(),
    }
    save_checkpoint(path, state)
    # The checkpoint's inference-only rule differs too (it acts in eval mode only; both run in training mode).
    model = DepthStitchNet(dataclasses.replace(DEPTH, first_surface=True, surface_rule=2.0), nominal_centres(0.4))
    assert _initialise_from(model, str(path)) == len(donor.state_dict())
    nn.init.constant_(model.surface_head.bias, -60.0)
    sample = make_sample(EXACT, 11)
    grids, masks, _ = nominal_unwarp_grids(EXACT)
    inputs, masks = unwarp(sample.fisheyes, grids)[None], masks.float()[None]
    with torch.no_grad():
        torch.testing.assert_close(model(inputs, masks).pano, donor(inputs, masks).pano, atol=1e-6, rtol=0)
    # A checkpoint of another network (here: other widths) shares only its same-shaped weights.
    other = DepthStitchNet(dataclasses.replace(DEPTH, widths=(4, 8, 16)), nominal_centres(0.4))
    save_checkpoint(
        path,
        {
            **state,
            "config": config_as_dict(StitchConfig(model=dataclasses.replace(DEPTH, widths=(4, 8, 16)))),
            "model": other.state_dict(),
        },
    )
    mine = model.state_dict()
    assert _initialise_from(model, str(path)) == sum(v.shape == mine[k].shape for k, v in other.state_dict().items())


def test_the_plane_colours_are_the_mean_of_the_inputs_that_see_each_plane():
    g = torch.Generator().manual_seed(2)
    samples = torch.rand(1, 3, 3, 2, 4, 5, generator=g, dtype=torch.float64)
    alpha = torch.ones(1, 3, 2, 4, 5, dtype=torch.float64)
    alpha[0, 2, 1] = 0.0  # input 2 does not see plane 1
    alpha[0, :2, 1, 0, 0] = 0.0  # pixel (0, 0) of plane 1: no input
    alpha[0, 0, 0, 1, 1] = 0.9  # a bilinear sample off the mask's edge does not take part
    samples = samples * alpha[:, :, None]
    colours, seen = plane_colours(samples, alpha)
    expected0 = samples[0, :, :, 0].mean(dim=0)
    expected0[:, 1, 1] = samples[0, 1:, :, 0, 1, 1].mean(dim=0)
    expected1 = samples[0, :2, :, 1].mean(dim=0)
    expected1[:, 0, 0] = 0.0
    torch.testing.assert_close(colours[0, :, 0], expected0)
    torch.testing.assert_close(colours[0, :, 1], expected1)
    assert seen[0, 1, 0, 0] == 0 and seen.sum() == 2 * 4 * 5 - 1


def test_the_plane_loss_is_the_expected_error_of_the_depth_distribution():
    g = torch.Generator().manual_seed(3)
    target = torch.rand(1, 3, 2, 2, generator=g)
    colours = torch.stack([target, target + 0.25, target - 0.5], dim=2)  # (1, 3, 3 planes, 2, 2)
    seen = torch.ones(1, 3, 2, 2)
    seen[0, 2, 0, 0] = 0.0  # plane 2 unseen at pixel (0, 0): error 1 there
    one_hot = torch.zeros(1, 3, 2, 2)
    one_hot[:, 0] = 1.0
    assert plane_loss(one_hot, colours, seen, target).item() == pytest.approx(0.0, abs=1e-7)
    mixed = torch.tensor([0.5, 0.25, 0.25])[None, :, None, None].expand(1, 3, 2, 2)
    expected = 0.25 * 0.25 + 0.25 * (3 * 0.5 + 1.0) / 4  # plane 1 everywhere; plane 2: 0.5 at three pixels, 1 at one
    assert plane_loss(mixed, colours, seen, target).item() == pytest.approx(expected, rel=1e-6)
    # Its gradient moves probability towards the plane that shows the truth.
    logits = torch.zeros(1, 3, 2, 2, requires_grad=True)
    plane_loss(torch.softmax(logits, dim=1), colours, seen, target).backward()
    assert (logits.grad[:, 0] < 0).all() and (logits.grad[:, 2] > 0).all()


def test_the_class_loss_is_the_cross_entropy_against_the_truths_two_nearest_planes():
    # Planes 0, 0.25, ..., 1 per metre; pixel (0, 0) at plane 2's depth, (0, 1) between planes 1 and
    # 2 (a quarter of the way), (1, 0) nearer than the nearest plane (clipped to plane 4), (1, 1)
    # where fewer than two inputs see the truth's plane (left out).
    probabilities = torch.tensor([0.1, 0.2, 0.3, 0.15, 0.25])[None, :, None, None].expand(1, 5, 2, 2)
    truth = torch.tensor([[[0.5, 0.3125], [3.0, 0.5]]])
    overlap = torch.ones(1, 5, 2, 2)
    overlap[0, 2, 1, 1] = 0.0
    expected = -(math.log(0.3) + (0.75 * math.log(0.2) + 0.25 * math.log(0.3)) + math.log(0.25)) / 3
    assert plane_class_loss(probabilities, overlap, truth, 1.0).item() == pytest.approx(expected, rel=1e-6)
    assert plane_class_loss(probabilities, torch.zeros(1, 5, 2, 2), truth, 1.0).item() == 0.0
    # Unlike the expected errors, it does not saturate: a network sure of the wrong plane still gets a
    # gradient of p - 1 (over the pixel count) at the true one.
    logits = torch.tensor([30.0, 0.0, 0.0, 0.0, 0.0])[None, :, None, None].repeat(1, 1, 2, 2).requires_grad_()
    plane_class_loss(torch.softmax(logits, dim=1), overlap, truth, 1.0).backward()
    assert logits.grad[0, 2, 0, 0].item() == pytest.approx(-1.0 / 3, rel=1e-6)
    assert logits.grad[0, 0, 0, 0].item() == pytest.approx(1.0 / 3, rel=1e-6)
    assert (logits.grad[0, :, 1, 1] == 0).all()
    with pytest.raises(ConfigError, match="loss.class_weight > 0 needs model.warp: depth"):
        config_from_dict({"loss": {"class_weight": 0.1}}, "h.yaml")


def test_the_surface_loss_is_the_cross_entropy_of_the_share_against_the_first_surface_being_right():
    # Pixel 0's first surface is within a plane of the truth, pixel 2's is not, pixel 1 has none.
    depth = torch.tensor([[0.5, -1.0, 1.0]])
    logit = torch.tensor([[2.0, 5.0, -1.0]])
    truth = torch.tensor([[0.55, 0.3, 0.5]])
    expected = (math.log1p(math.exp(-2.0)) + math.log1p(math.exp(-1.0))) / 2.0
    assert float(surface_loss(depth, logit, 0.087, truth)) == pytest.approx(expected, rel=1e-6)
    assert float(surface_loss(torch.full((1, 3), -1.0), logit, 0.087, truth)) == 0.0
    with pytest.raises(ConfigError, match="loss.surface_weight > 0 needs model.first_surface: true"):
        config_from_dict({"model": {"warp": "depth"}, "loss": {"surface_weight": 0.1}}, "h.yaml")


def test_the_smooth_fill_keeps_confident_pixels_fills_holes_from_around_them_and_wraps():
    g = torch.Generator().manual_seed(3)
    height, width = 32, 64
    pano = torch.rand(2, 3, height, width, generator=g)
    # Whole confidence everywhere: the panorama itself.
    torch.testing.assert_close(smooth_fill(pano, torch.ones(2, height, width)), pano)
    # A hole in a constant panorama takes the constant, whatever the hole holds.
    flat = torch.full((1, 3, height, width), 0.3)
    confidence = torch.ones(1, height, width)
    flat[..., 20:30, 10:40] = 5.0
    confidence[..., 20:30, 10:40] = 0.0
    torch.testing.assert_close(smooth_fill(flat, confidence), torch.full_like(flat, 0.3))
    # A hole between a dark and a bright side is filled between the two, darker near the dark side.
    ramp = torch.where(torch.arange(width) < width // 2, 0.1, 0.9).expand(1, 3, height, width).clone()
    confidence = torch.ones(1, height, width)
    confidence[..., :, 24:40] = 0.0
    row = smooth_fill(ramp, confidence)[0, 0, height // 2, 24:40]
    assert (row > 0.1).all() and (row < 0.9).all() and row[0] < 0.5 < row[-1]
    # The panorama wraps: turning it by half a turn turns the fill with it (a fill that stopped at
    # the +-180 degree edge would differ there).
    confidence = (torch.rand(2, height, width, generator=g) > 0.7).float()
    fill = smooth_fill(pano, confidence)
    turned = smooth_fill(pano.roll(width // 2, dims=-1), confidence.roll(width // 2, dims=-1))
    torch.testing.assert_close(turned, fill.roll(width // 2, dims=-1))
    # A panorama read only where its confidence is: what the zero-confidence pixels hold never counts.
    changed = torch.where(confidence[:, None] > 0, pano, torch.rand(pano.shape, generator=g))
    torch.testing.assert_close(smooth_fill(changed, confidence), fill)


def _ground_only_sample(config: SynthConfig, seed: int = 5) -> tuple[Sample, object]:
    """A sample of a scene with the ground alone (no buildings, poles, cars ...) and the rig's design."""
    scene = sample_scene(seed)
    empty = {}
    for field in dataclasses.fields(scene):
        value = getattr(scene, field.name)
        if field.name.startswith(("box_", "cyl_", "sph_")):
            empty[field.name] = value[:0]
    scene = dataclasses.replace(scene, **empty)
    rng = np.random.default_rng(0)
    rig = sample_rig(rng, config.fisheye_size, config.hfov, config.distance, 0.0, 0.0)
    rays = torch.as_tensor(pano_rays(config.pano_width, config.pano_height), dtype=torch.float32)
    pano, depth = render(scene, torch.zeros(3), rays)
    empty_images = torch.zeros(3, 3, config.fisheye_size, config.fisheye_size)
    sample = Sample(
        seed,
        empty_images,
        torch.ones(3, config.fisheye_size, config.fisheye_size, dtype=torch.bool),
        pano.permute(2, 0, 1),
        depth,
        rig,
        config.circle_deg,
    )
    return sample, scene


def test_the_seen_mask_of_a_ground_only_scene_is_its_closed_form_blind_spot():
    config = dataclasses.replace(EXACT, pano_width=256)
    sample, scene = _ground_only_sample(config)
    lines = sight_lines(sample, config, scene)
    # Closed form: panorama ray w below the horizon meets the ground y = h at P = w h / w_y; camera
    # i sees P when the angle between P - c_i and its axis is at most half the circle. The sky is
    # seen by every camera whose circle holds w, and the three circles cover all of it.
    rays = pano_rays(config.pano_width, config.pano_height)
    centres = nominal_centres(config.distance)
    axes = centres / np.linalg.norm(centres, axis=-1, keepdims=True)
    below = rays[..., 1] > 1e-9
    points = np.where(
        below[..., None], rays * (scene.camera_height / np.where(below, rays[..., 1], 1.0))[..., None], 0.0
    )
    towards = points[None] - centres[:, None, None]
    cos = np.einsum("khwi,ki->khw", towards, axes) / np.linalg.norm(towards, axis=-1)
    sky_cos = np.einsum("hwi,ki->khw", rays, axes)
    half = math.radians(config.circle_deg / 2.0)
    seen = np.where(below, (cos >= math.cos(half)).any(axis=0), (sky_cos >= math.cos(half)).any(axis=0))
    agree = lines.seen.numpy() == seen
    # Only pixels within a hair of the circle's edge may differ (float32 against float64).
    margin = np.abs(np.degrees(np.arccos(np.clip(np.where(below, cos, sky_cos), -1, 1))) - config.circle_deg / 2).min(
        axis=0
    )
    assert np.all(agree | (margin < 0.05))
    blind = 1.0 - seen.mean()
    assert 0.02 < blind < 0.2  # the ground under the rig
    assert abs((1.0 - lines.seen.float().mean().item()) - blind) < 1e-3


def test_an_occluded_point_is_not_seen_and_the_sky_is():
    config = dataclasses.replace(EXACT, pano_width=256)
    sample = make_sample(config, 1_000_000_000)
    lines = sight_lines(sample, config)
    sky = torch.isinf(sample.depth)
    assert lines.seen[sky].float().mean() > 0.95
    # A sky pixel no input sees is hidden from each camera whose circle holds it by something near.
    scene = sample_scene(sample.seed)
    rays = torch.as_tensor(pano_rays(256, 128), dtype=torch.float32)
    hidden = sky & ~lines.seen
    for k in range(3):
        centre = torch.as_tensor(sample.rig.centres[k], dtype=torch.float32)
        in_circle = hidden & (lines.theta[k] <= EXACT.circle_deg / 2)
        assert torch.isfinite(render(scene, centre, rays[in_circle])[1]).all()
    # Rendering each input along its sight lines to a point it sees gives the point's distance.
    k = 1
    visible = lines.visible[k] & ~sky
    points = sample.depth[visible, None] * rays[visible]
    centre = torch.as_tensor(sample.rig.centres[k], dtype=torch.float32)
    _, reached = render(scene, centre, lines.directions[k][visible])
    torch.testing.assert_close(reached, (points - centre).norm(dim=-1), rtol=2e-3, atol=2e-3)
    assert (~lines.visible[k] & ~sky & (lines.theta[k] < 80)).any()  # near objects hide something from camera 1


def test_the_rig_aware_warp_fed_the_true_depth_reproduces_the_depth_oracle():
    sample = make_sample(EXACT, 1_000_000_003)
    lines = sight_lines(sample, EXACT)
    grids, masks, _ = nominal_unwarp_grids(EXACT)
    x = torch.cat([unwarp(sample.fisheyes, grids), masks.float()[:, None]], dim=1)[None]
    net = build_model(DEPTH, EXACT)
    identity = torch.eye(3).expand(1, 3, 3, 3)
    true_depth = net.warp(x, (1.0 / sample.depth)[None], identity)[0]
    at_infinity = net.warp(x, torch.zeros_like(sample.depth)[None], identity)[0]
    oracle = F.grid_sample(sample.fisheyes, lines.grid, align_corners=False)  # every input along its sight line
    for i in range(3):
        inside = (true_depth[i, 3] > 0.999) & (lines.grid[i].abs() <= 0.95).all(dim=-1) & (lines.theta[i] < 85)
        close = psnr(true_depth[i, :3], oracle[i], inside).item()
        far = psnr(at_infinity[i, :3], oracle[i], inside).item()
        assert close > 29.0 and close > far + 8.0, (i, close, far)  # bilinear twice against once; far: parallax
    # The panorama: the true depth with the oracle's own weights gives the oracle's stitch.
    weights = feather_weights(lines.theta, lines.visible, EXACT.circle_deg)
    stitched = (true_depth[:, :3] * weights[:, None]).sum(dim=0)
    fallback, _ = rotation_only_stitch(sample.fisheyes, sample.rig, EXACT)
    reference = depth_oracle_stitch(sample.fisheyes, lines, EXACT, fallback)
    seen = lines.seen
    assert psnr(stitched, sample.pano, seen) > psnr(reference, sample.pano, seen) - 0.5
    assert psnr(stitched, reference, seen) > 30.0


def test_where_no_input_sees_along_the_predicted_depth_the_panorama_falls_back_to_infinity():
    sample = make_sample(EXACT, 1_000_000_003)
    grids, masks, _ = nominal_unwarp_grids(EXACT)
    inputs, masks = unwarp(sample.fisheyes, grids)[None], masks.float()[None]
    net = build_model(DEPTH, EXACT).eval()
    height, width = masks.shape[-2:]
    # A point 2 cm from the centre lies behind every camera: each samples behind its own lens. The
    # right half at 3 m: seen.
    behind = torch.full((1, height, width), 50.0)
    behind[..., width // 2 :] = 1.0 / 3.0
    with torch.no_grad():
        hole = net(inputs, masks, inverse_depth=behind)
        far = net(inputs, masks, inverse_depth=torch.zeros(1, height, width))
        x = torch.cat([inputs, masks[:, :, None]], dim=2)
        sees = net.warp(x, behind, torch.eye(3).expand(1, 3, 3, 3))[:, :, 3].amax(dim=1)[0] > 0
    fallback = ~sees
    assert fallback[:, : width // 2].all() and sees[:, width // 2 :].float().mean() > 0.8
    covered = masks[0].amax(dim=0) > 0
    assert (hole.coverage[0][covered] > 0).all()  # no hole where an input covers the direction
    torch.testing.assert_close(hole.pano[0][:, fallback], far.pano[0][:, fallback], atol=1e-5, rtol=0)
    assert hole.weights[0, :, 1][:, sees].max() < 1e-6  # the fallback takes no share where a depth warp sees


def test_the_untrained_rig_aware_network_takes_the_cost_minimum_and_beats_the_true_rotation_stitch():
    config = dataclasses.replace(EXACT, fisheye_size=128, pano_width=256)
    model = DepthStitchNet(dataclasses.replace(DEPTH, depth_planes=16), nominal_centres(config.distance))
    grids, masks, _ = nominal_unwarp_grids(config)
    gains = []
    for seed in (1_000_000_000, 1_000_000_001):
        sample = make_sample(config, seed)
        seen = sight_lines(sample, config).seen
        with torch.no_grad():
            out = model(unwarp(sample.fisheyes, grids)[None], masks.float()[None])
        baseline, _ = rotation_only_stitch(sample.fisheyes, sample.rig, config)
        gains.append(psnr(out.pano[0], sample.pano, seen).item() - psnr(baseline, sample.pano, seen).item())
        assert out.inverse_depth.shape == (1, 128, 256) and out.weights.shape == (1, 3, 2, 128, 256)
        torch.testing.assert_close(out.rotations, torch.eye(3).expand(1, 3, 3, 3))
    assert min(gains) > 0.5, gains


def test_the_rig_aware_network_trains_and_its_config_is_checked():
    config = config_from_dict(
        {
            "model": {"warp": "depth", "widths": [4, 8, 8], "regressor_width": 8, "head_width": 4, "depth_planes": 4},
            "data": {"fisheye_size": 32, "pano_width": 64},
            "loss": {"depth_weight": 0.5},
        },
        "d.yaml",
    )
    model = build_model(config.model, config.data)
    g = torch.Generator().manual_seed(1)
    inputs, masks = torch.rand(2, 3, 3, 32, 64, generator=g), torch.ones(2, 3, 32, 64)
    out = model(inputs, masks)
    (out.pano.mean() + out.inverse_depth.mean()).backward()
    assert model.rotation.weight.grad.abs().sum() > 0 and model.depth_head.weight.grad.abs().sum() > 0
    with torch.no_grad():
        off = model(inputs, masks, gain=False)
    assert torch.isfinite(off.pano).all()
    for key in ("depth_weight", "plane_weight"):
        with pytest.raises(ConfigError, match=f"loss.{key} > 0 needs model.warp: depth"):
            config_from_dict({"loss": {key: 0.5}}, "h.yaml")
    with pytest.raises(ConfigError, match="fill: true needs warp: depth"):
        config_from_dict({"model": {"fill": True}}, "h.yaml")


def test_the_fill_and_the_plane_loss_train_the_rig_aware_network():
    config = config_from_dict(
        {
            "model": {**DEPTH_VALUES, "depth_planes": 4, "fill": True},
            "data": {"fisheye_size": 32, "pano_width": 64},
            "loss": {"plane_weight": 0.5},
        },
        "d.yaml",
    )
    model = build_model(config.model, config.data)
    g = torch.Generator().manual_seed(4)
    inputs, masks, target = torch.rand(2, 3, 3, 32, 64, generator=g), torch.ones(2, 3, 32, 64), torch.rand(2, 3, 32, 64)
    out = model(inputs, masks, planes=True)
    assert out.plane_colours.shape == (2, 3, 4, 32, 64) and out.plane_seen.shape == (2, 4, 32, 64)
    torch.testing.assert_close(out.plane_probabilities.sum(dim=1), torch.ones(2, 32, 64))
    sweep = {"max_inverse_depth": config.model.max_inverse_depth, "depth_planes": config.model.depth_planes}
    loss, terms = StitchLoss(config.loss, **sweep)(out, {"pano": target})
    assert set(terms) == {"pixel", "ssim", "plane"}
    loss.backward()
    assert model.depth_head.weight.grad.abs().sum() > 0 and model.fill_head.weight.grad.abs().sum() > 0
    model.eval()
    with torch.no_grad():
        plain = model(inputs, masks)
        assert plain.plane_probabilities is None and plain.plane_colours is None  # only when asked
        model.fill_head.bias.fill_(-50.0)  # no fill: the blend alone
        blended = model(inputs, masks)
        # The fill takes every pixel: the panorama is the blend's smooth fill, which then reads every
        # pixel alike (at the floor of its confidence).
        model.fill_head.bias.fill_(50.0)
        filled = model(inputs, masks).pano
    floor = torch.full_like(blended.coverage, _FILL_FLOOR)
    torch.testing.assert_close(filled, smooth_fill(blended.pano, floor))
    assert (filled - blended.pano).abs().max() > 0.01
    with pytest.raises(ConfigError, match="plane_weight > 0 needs a network that predicts depth"):
        StitchLoss(LossConfig(plane_weight=1.0))(plain, {"pano": target})
    with pytest.raises(ConfigError, match="warp must be 'homography' or 'depth', got 'flow'"):
        config_from_dict({"model": {"warp": "flow"}}, "f.yaml")
    with pytest.raises(ConfigError, match="expected inputs \\(B, 3, 3, H, W\\)"):
        model(inputs[:, :2], masks[:, :2])


@pytest.mark.parametrize("term, model", [("plane", {}), ("class", {"ghost_cost": True})])
def test_training_with_the_plane_or_class_loss_asks_the_network_for_its_planes(tmp_path, term, model):
    # The training loop asks for the plane outputs only when loss.plane_weight or class_weight > 0;
    # the loss refuses to go on without them, so a step that logs the term got them.
    values = {
        "model": {**DEPTH_VALUES, "depth_planes": 4, "fill": True, **model},
        "data": {"fisheye_size": 32, "pano_width": 64},
        "loss": {f"{term}_weight": 0.5},
        "train": {
            "samples": 2,
            "batch_size": 2,
            "epochs": 1,
            "log_every": 1,
            "data_dir": str(tmp_path / "data"),
            "synth_workers": 1,
        },
    }
    train(config_from_dict(values, "d.yaml"), tmp_path / "run", progress=False)
    (record,) = [json.loads(line) for line in (tmp_path / "run" / "metrics.jsonl").read_text().splitlines()]
    assert record[term] > 0


def test_calibrated_inputs_are_unwarped_at_each_samples_own_cameras(tmp_path):
    config = SynthConfig(fisheye_size=48, pano_width=64, distance=0.4)
    generated = GeneratedDataset(config, "train", 2, inputs="calibrated")[1]
    sample = make_sample(config, 1)
    grids, masks, _ = unwarp_grids(sample.rig.cameras, (64, 32), config.circle_deg)
    torch.testing.assert_close(generated["inputs"], unwarp(sample.fisheyes, grids))
    torch.testing.assert_close(generated["masks"], masks.float())
    nominal = GeneratedDataset(config, "train", 2)[1]
    assert (generated["inputs"] - nominal["inputs"]).abs().mean() > 0.01  # the jitter the calibration removes
    # From disk: the cameras come from each sample's sample.json; the images through PNG.
    synthesise(config, tmp_path, num=2, progress=False)
    stored = FolderDataset(tmp_path, "train", inputs="calibrated")[1]
    torch.testing.assert_close(stored["masks"], generated["masks"])
    assert (stored["inputs"] - generated["inputs"]).abs().max() <= 1.0 / 255 + 1e-6
    # A model of calibrated inputs refuses to stitch without the rig's cameras.
    values = {"model": {**DEPTH_VALUES, "inputs": "calibrated"}, "data": {"fisheye_size": 48, "pano_width": 64}}
    stitch_config = config_from_dict(values, "c.yaml")
    model = build_model(stitch_config.model, stitch_config.data).eval()
    with pytest.raises(ConfigError, match="pass the calibrated cameras"):
        stitch_fisheyes(model, sample.fisheyes, stitch_config.data)
    pano = stitch_fisheyes(model, sample.fisheyes, stitch_config.data, cameras=sample.rig.cameras)
    assert pano.shape == (3, 32, 64)


def test_the_shipped_rig_aware_model_runs_under_bfloat16_autocast():
    """As on a GPU (bfloat16 autocast): the encoder, decoder and heads in bfloat16, the warps and
    the blend in float32; the panorama stays within what bfloat16's rounding of the logits moves."""
    from learnstitch.checkpoint import load_model
    from learnstitch.inference import SHIPPED_MODEL

    model, trained = load_model(SHIPPED_MODEL)
    config = trained.data
    sample = make_sample(config, 1_000_000_000)
    grids, masks, _ = nominal_unwarp_grids(config)
    inputs, masks = unwarp(sample.fisheyes, grids)[None], masks.float()[None]
    with torch.no_grad():
        full = model(inputs, masks)
        with torch.autocast("cpu", dtype=torch.bfloat16):
            half = model(inputs, masks)
    assert half.pano.dtype == torch.float32
    assert psnr(half.pano[0], full.pano[0]).item() > 35.0  # against the float32 panorama, not the truth
