"""The working depth refined by the full-resolution inputs' agreement (learnstitch.fullres.refine),
against closed forms: a textured plane ray cast through rigjax's camera model, whose inverse depth
along every panorama ray is known; the ray-cast street sample's own depth; slow dense references of
the filters."""

import dataclasses

import cv2
import numpy as np
import pytest
import torch
import torch.nn.functional as F
from test_fullres import _tri_sample  # tests/learnstitch/test_fullres.py: a street sample and its rig

import rigjax
from learnstitch.data.visibility import sight_lines
from learnstitch.fullres.config import RenderConfig
from learnstitch.fullres.depth import pano_rays, upsample, upsample_canvas
from learnstitch.fullres.refine import _box, _guided_filter, level_widths, refine_depth
from learnstitch.fullres.rig import Rig
from learnstitch.fullres.stitcher import Frame, Stitcher, float_images
from rigjax import Camera
from rigjax.errors import ConfigError
from rigjax.synthetic import procedural_environment

# The shipped network's planes: 24 from infinity to 0.5 m.
SHIPPED = RenderConfig(depth_planes=24, max_inverse_depth=2.0, photometry="none")
PLANE = SHIPPED.max_inverse_depth / (SHIPPED.depth_planes - 1)


def _plane_rig(distance=2.0, baseline=0.4, size=320, width=512):
    """Two 100-degree rectilinear cameras ``baseline`` apart along x, both looking along +z at a
    textured plane ``z = distance`` (metres): the rig (panorama ``width`` wide) with their images
    ray cast through rigjax's lens model, and the plane's inverse depth along every ray of a canvas
    (0 where a ray misses it)."""
    cameras = Camera.create(
        projection=np.zeros(2, np.int32), width=np.full(2, size), height=np.full(2, size), hfov=np.full(2, 100.0), xp=np
    )
    centres = np.array([[-baseline / 2, 0.0, 0.0], [baseline / 2, 0.0, 0.0]])
    texture = procedural_environment(1024, seed=3)  # on the plane, 128 texels per metre, centred on the axis
    ys, xs = np.mgrid[0:size, 0:size].astype(np.float64)
    images = []
    for k in range(2):
        camera = Camera(*(np.asarray(v)[k] for v in cameras))
        rays, _ = rigjax.img_to_ray(camera, np.stack([xs, ys], -1))
        rays = np.asarray(rays)
        t = (distance - centres[k, 2]) / rays[..., 2]
        point = centres[k] + t[..., None] * rays
        u = (point[..., 0] * 128.0 + 512.0).astype(np.float32)
        v = (point[..., 1] * 128.0 + 256.0).astype(np.float32)
        images.append(cv2.remap(texture, u, v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT))

    def truth(canvas: int) -> torch.Tensor:
        rays = pano_rays(canvas, canvas // 2)
        return torch.where(rays[..., 2] > 0, rays[..., 2] / distance, torch.zeros(()))

    return Rig(cameras, centres, images, ["left", "right"], width, True), truth


def _refined(rig, prior, config, widths):
    stitcher = Stitcher.prepare(rig, rig.width, config, circle_deg=np.full(2, 360.0))
    frame = Frame(float_images(rig.images), stitcher.tables)
    return refine_depth(frame.working, stitcher.tables, prior, None, config, widths)


def test_on_a_textured_plane_it_reaches_the_planes_depth_to_a_tenth_of_a_plane_from_one_plane_off():
    rig, truth = _plane_rig()
    widths = level_widths(SHIPPED, rig.width)  # 64, 128 and 256 around
    # The plane's depth one plane off, on a canvas an eighth of the panorama's width (the shipped
    # network's 256 for a 2048-wide panorama).
    prior = truth(64) + PLANE
    got = _refined(rig, prior, SHIPPED, widths)
    expected = truth(widths[-1])
    told = got.confidence > 0
    assert told.float().mean() > 0.1  # the two cameras' overlap, on the canvas
    start = (upsample_canvas(prior, widths[-1]) - expected).abs()[told]
    assert start.min() > 0.9 * PLANE  # where it was
    error = (got.inverse_depth - expected).abs()[told] / PLANE
    # Typically a twentieth of a plane, eight pixels in ten within a tenth (0.0087 m^-1; a third of a
    # pixel of the finest canvas here), nineteen in twenty within a quarter.
    assert error.median() < 0.05 and (error < 0.1).float().mean() > 0.8, (error.median(), (error < 0.1).float().mean())
    assert (error < 0.25).float().mean() > 0.95
    # Behind the cameras neither sees anything: the prior stays.
    behind = expected == 0
    assert torch.equal(got.inverse_depth[behind], upsample_canvas(prior, widths[-1])[behind])


def _street():
    return _tri_sample(0.4, 192, seed=11)  # three 192-pixel fisheyes 0.4 m out, a 384-wide panorama


def test_fed_the_true_depth_it_stays_on_it():
    config, sample, rig = _street()
    lines = sight_lines(sample, config)
    truth = torch.where(torch.isfinite(sample.depth), 1.0 / sample.depth, torch.zeros_like(sample.depth))
    settings = RenderConfig(photometry="none", refine_levels=1, refine_scale=1.0)
    stitcher = Stitcher.prepare(rig, rig.width, settings, circle_deg=np.full(3, 185.0))
    frame = Frame(float_images(rig.images), stitcher.tables)
    got = refine_depth(frame.working, stitcher.tables, truth, None, settings, [rig.width])
    spacing = settings.max_inverse_depth / (settings.depth_planes - 1)
    # Where two inputs truly see the point, away from depth edges (where a pixel's footprint spans
    # two surfaces) and where the scene has texture to match (the grey's deviation over 5 x 5 pixels).
    smooth = F.max_pool2d(truth[None, None], 5, 1, 2)[0, 0] + F.max_pool2d(-truth[None, None], 5, 1, 2)[0, 0] < 0.02
    grey = sample.pano.mean(dim=0)[None, None]
    texture = (F.avg_pool2d(grey**2, 5, 1, 2) - F.avg_pool2d(grey, 5, 1, 2) ** 2).clamp_min(0.0).sqrt()[0, 0]
    where = smooth & (texture > 0.02) & (lines.visible.sum(dim=0) >= 2) & (got.confidence > 0)
    assert where.sum() > 1000
    moved = (got.inverse_depth - truth).abs()[where] / spacing
    assert moved.median() < 0.15 and (moved > 0.5).float().mean() < 0.05, (moved.median(), (moved > 0.5).float().mean())


def test_from_a_coarse_depth_a_plane_too_far_it_moves_toward_the_truth_in_the_seams():
    config, sample, rig = _street()
    lines = sight_lines(sample, config)
    truth = torch.where(torch.isfinite(sample.depth), 1.0 / sample.depth, torch.zeros_like(sample.depth))
    # The truth's depth a plane too far, on a canvas an eighth of the panorama's width: a coarse network's.
    prior = F.avg_pool2d((truth - PLANE).clamp_min(0.0)[None, None], 8)[0, 0]
    settings = RenderConfig(photometry="none", depth_planes=24, refine_scale=1.0)
    stitcher = Stitcher.prepare(rig, rig.width, settings, circle_deg=np.full(3, 185.0))
    frame = Frame(float_images(rig.images), stitcher.tables)
    widths = level_widths(settings, rig.width)
    got = refine_depth(frame.working, stitcher.tables, prior, None, settings, widths)
    # Where two inputs truly see the point, away from depth edges, with texture to match.
    smooth = F.max_pool2d(truth[None, None], 3, 1, 1)[0, 0] + F.max_pool2d(-truth[None, None], 3, 1, 1)[0, 0] < 0.02
    grey = sample.pano.mean(dim=0)[None, None]
    texture = (F.avg_pool2d(grey**2, 5, 1, 2) - F.avg_pool2d(grey, 5, 1, 2) ** 2).clamp_min(0.0).sqrt()[0, 0]
    where = smooth & (texture > 0.02) & (lines.visible.sum(dim=0) >= 2) & (truth > 0)
    assert where.sum() > 1000
    before = (upsample_canvas(prior, rig.width) - truth).abs()[where] / PLANE
    after = (got.inverse_depth - truth).abs()[where] / PLANE
    assert before.median() > 0.9 and after.median() < 0.5 * before.median(), (before.median(), after.median())


def test_box_and_guided_filters_equal_dense_references():
    generator = torch.Generator().manual_seed(0)
    x = torch.rand(3, 12, 24, generator=generator)
    padded = F.pad(F.pad(x[None], (2, 2, 0, 0), mode="circular"), (0, 0, 2, 2), mode="replicate")
    assert torch.allclose(_box(x, 2), F.avg_pool2d(padded, 5, stride=1)[0], atol=1e-6)
    # The guided filter: per window, least squares x ~ a g + b, the windows' (a, b) averaged at each pixel.
    guide = torch.rand(12, 24, generator=generator)
    r, eps = 1, 1e-3
    gp = F.pad(F.pad(guide[None, None], (r, r, 0, 0), mode="circular"), (0, 0, r, r), mode="replicate")[0, 0]
    xp = F.pad(F.pad(x[None], (r, r, 0, 0), mode="circular"), (0, 0, r, r), mode="replicate")[0]
    a = torch.zeros(3, 12, 24, dtype=torch.float64)
    b = torch.zeros_like(a)
    for i in range(12):
        for j in range(24):
            g = gp[i : i + 3, j : j + 3].double().reshape(-1)
            for c in range(3):
                v = xp[c, i : i + 3, j : j + 3].double().reshape(-1)
                a[c, i, j] = ((g * v).mean() - g.mean() * v.mean()) / (g.var(unbiased=False) + eps)
                b[c, i, j] = v.mean() - a[c, i, j] * g.mean()
    ab = _box(torch.cat([a, b]).float(), r)
    expected = ab[:3] * guide + ab[3:]
    assert torch.allclose(_guided_filter(guide, x, r), expected, atol=1e-5)


def test_working_maps_brought_up_on_whole_factors_equal_the_renderers_bilinear():
    maps = torch.rand(2, 16, 32, generator=torch.Generator().manual_seed(1))
    for width in (32, 64, 128, 96):
        expected = torch.stack(
            [upsample(m, width, width // 2, 0, width // 2, 0.0).value.reshape(width // 2, width) for m in maps]
        )
        assert torch.allclose(upsample_canvas(maps, width), expected, atol=1e-5)


def test_level_widths_and_bad_refinement_settings():
    assert level_widths(RenderConfig(), 2048) == [256, 512, 1024]
    assert level_widths(RenderConfig(refine_levels=2, refine_scale=1.0), 1000) == [500, 1000]
    assert level_widths(RenderConfig(), 512, 512) == [128, 256, 512]  # ends no coarser than the depth it starts from
    assert level_widths(RenderConfig(), 256, 512) == [64, 128, 256]  # nor finer than the output
    assert level_widths(RenderConfig(), 8192, 256) == [512, 1024, 2048]  # refine_max_width
    for key, value in (
        ("refine_levels", -1),
        ("refine_scale", 0.0),
        ("refine_max_width", 15),
        ("refine_steps", 0),
        ("refine_radius", -1),
        ("refine_truncation", 0.0),
        ("refine_prior", -0.1),
        ("refine_min_confidence", 1.0),
    ):
        with pytest.raises(ConfigError, match=key):
            RenderConfig(**{key: value})


def test_sampled_a_tile_at_a_time_it_is_the_same():
    rig, truth = _plane_rig(width=256)
    prior = truth(64) + PLANE
    whole = _refined(rig, prior, SHIPPED, [64, 128])
    tiled = _refined(rig, prior, dataclasses.replace(SHIPPED, tile_pixels=1000), [64, 128])
    # Float sums vectorised over other lengths: equal to rounding.
    torch.testing.assert_close(tiled.inverse_depth, whole.inverse_depth, atol=1e-5, rtol=0)
    torch.testing.assert_close(tiled.confidence, whole.confidence, atol=1e-4, rtol=0)
