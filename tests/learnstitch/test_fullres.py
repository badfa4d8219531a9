"""Full-resolution stitching of any calibrated rig (learnstitch.fullres), against independent
references: rigjax's camera model in float64, torch's bilinear interpolation, the environment a rig
at infinity was rendered from, and learnstitch's own true-rotation stitch and depth oracle."""

import dataclasses

import cv2
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import torch
import torch.nn.functional as F

import rigjax
from learnstitch import cli
from learnstitch.baselines import depth_oracle_stitch, psnr, rotation_only_stitch
from learnstitch.data.rig import pano_rays as rigjax_pano_rays
from learnstitch.data.rig import unwarp_grids
from learnstitch.data.sample import SynthConfig, make_sample
from learnstitch.data.store import to_uint8
from learnstitch.data.visibility import sight_lines
from learnstitch.fullres.config import RenderConfig
from learnstitch.fullres.depth import bring_up, pano_rays, upsample, working_images
from learnstitch.fullres.occlusion import unoccluded
from learnstitch.fullres.rig import Rig, image_circle_px, image_circles_px, load_rig, photometry_undone
from learnstitch.fullres.sight import sight_tables, views
from learnstitch.fullres.stitcher import GivenDepth, Stitcher, float_images, stitch_rig
from learnstitch.inference import SHIPPED_MODEL, stitch_project
from rigjax import Camera
from rigjax.errors import ConfigError
from rigjax.rendering.images import ImageError
from rigjax.synthetic import procedural_environment, render_images, rig_from_orientations

NO_PHOTOMETRY = RenderConfig(photometry="none")


def _cameras(**fields) -> Camera:
    return Camera.create(**{k: np.asarray(v, np.float64) if k != "projection" else v for k, v in fields.items()}, xp=np)


def test_sight_tables_read_rigjax_camera_model_to_a_hundredth_of_a_pixel():
    # Four lenses (circular, rectilinear, full-frame fisheye, stereographic), distortion, shifts and
    # orientations anywhere; the reference is rigjax's ray_to_img in float64 at each direction.
    cameras = _cameras(
        projection=np.array([2, 0, 3, 10]),
        width=[1024, 640, 800, 900],
        height=[1024, 480, 600, 700],
        hfov=[185, 90, 150, 160],
        b=[0, -0.01, 0.01, 0],
        d=[0, 3, -2, 0],
        yaw=[0, 120, -100, 30],
        pitch=[5, -10, 20, 80],
        roll=[0, 3, -40, 10],
    )
    rng = np.random.default_rng(0)
    directions = rng.normal(size=(20000, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    tables = sight_tables(cameras, np.zeros((4, 3)), 1024)
    seen = views(tables, torch.as_tensor(directions, dtype=torch.float32), torch.zeros(len(directions)))
    for k in range(4):
        with jax.enable_x64(True):
            camera = jax.tree_util.tree_map(lambda v, k=k: jnp.asarray(np.asarray(v)[k]), cameras)
            exact, mapped = rigjax.ray_to_img(camera, jnp.asarray(directions))
        exact = np.asarray(exact)
        visible = seen.visible[k].numpy()
        inside = np.asarray(mapped) & np.all(
            (exact >= -0.5) & (exact <= np.array([cameras.width[k], cameras.height[k]]) - 0.5), -1
        )
        assert visible.sum() > 1000 and not np.any(visible & ~inside)
        assert np.linalg.norm(seen.xy[k].numpy() - exact, axis=1)[visible].max() < 0.01


def test_panorama_rays_are_rigjax_canvas_rays():
    np.testing.assert_allclose(pano_rays(64, 32).numpy(), rigjax_pano_rays(64, 32), atol=1e-6)
    np.testing.assert_allclose(pano_rays(64, 32, 5, 7).numpy(), rigjax_pano_rays(64, 32)[5:12], atol=1e-6)


def test_upsample_interpolates_bilinearly_and_marks_depth_edges():
    working = torch.rand(8, 16, generator=torch.Generator().manual_seed(0))
    up = upsample(working, 64, 32, 0, 32, 0.0)
    # torch's bilinear interpolation of the canvas, wrapped across +-180 degrees (a column each side)
    padded = torch.cat([working[:, -1:], working, working[:, :1]], dim=1)
    reference = F.interpolate(padded[None, None], scale_factor=4, mode="bilinear", align_corners=False)[0, 0]
    torch.testing.assert_close(up.value.reshape(32, 64), reference[:, 4:-4], atol=1e-5, rtol=0)
    step = torch.zeros(8, 16)
    step[:, 8:] = 1.0
    edge = upsample(step, 64, 32, 0, 32, 10.0).edge.reshape(32, 64)
    assert edge[:, 30:34].all() and not edge[:, 34:62].any() and edge[:, :2].all()  # the step and the wrap


def test_working_maps_come_up_bilinearly_across_the_wrap_in_any_rows():
    maps = torch.rand(3, 8, 16, generator=torch.Generator().manual_seed(1))
    padded = torch.cat([maps[..., -1:], maps, maps[..., :1]], dim=-1)
    reference = F.interpolate(padded[None], scale_factor=4, mode="bilinear", align_corners=False)[0][..., 4:-4]
    whole, some_rows = (upsample(torch.zeros(8, 16), 64, 32, row0, rows, 0.0) for row0, rows in ((0, 32), (9, 5)))
    torch.testing.assert_close(bring_up(maps, whole).reshape(3, 32, 64), reference, atol=1e-5, rtol=0)
    torch.testing.assert_close(bring_up(maps, some_rows).reshape(3, 5, 64), reference[:, 9:14], atol=1e-5, rtol=0)


def _tri_sample(distance=0.4, size=128, seed=7):
    config = SynthConfig(
        fisheye_size=size,
        pano_width=2 * size,
        distance=distance,
        hfov_jitter_deg=0.0,
        gain_jitter=0.0,
        vignetting=0.0,
        noise_std=0.0,
    )
    sample = make_sample(config, seed)
    rig = Rig(
        sample.rig.cameras,
        np.asarray(sample.rig.centres),
        [to_uint8(f) for f in sample.fisheyes],
        list("abc"),
        2 * size,
        True,
    )
    return config, sample, rig


def _as_float(pano: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(pano).permute(2, 0, 1).float() / 255.0


def test_with_every_centre_at_the_origin_it_is_the_true_rotation_stitch():
    config, sample, rig = _tri_sample()
    expected = to_uint8(rotation_only_stitch(sample.fisheyes, sample.rig, config)[0]).astype(float)
    got = stitch_rig(rig._replace(centres=np.zeros((3, 3))), 256, NO_PHOTOMETRY, circle_deg=np.full(3, 185.0))
    difference = np.abs(got.pano.astype(float) - expected).max(axis=-1)
    # Within sqrt 2 fisheye pixels of an image circle the true-rotation stitch reads the black beyond
    # it (bilinear samples reaching past the last pixel), which the renderer does not: those pixels
    # may differ.
    _, masks, theta = unwarp_grids(sample.rig.cameras, (256, 128), 185.0)
    edge = (masks & (92.5 - theta < 1.5 * 185.0 / 128)).any(dim=0).numpy()
    assert difference[~edge].max() <= 2 and difference[~edge].mean() < 0.5
    assert not got.inverse_depth.any()


def test_fed_the_true_depth_it_is_the_depth_oracle():
    config, sample, rig = _tri_sample()
    lines = sight_lines(sample, config)
    oracle = depth_oracle_stitch(
        sample.fisheyes, lines, config, rotation_only_stitch(sample.fisheyes, sample.rig, config)[0]
    )
    inverse_depth = torch.where(torch.isfinite(sample.depth), 1.0 / sample.depth, torch.zeros_like(sample.depth))
    oracle_depth = GivenDepth(full=inverse_depth, visibility=lines.visible)
    got = stitch_rig(rig, 256, NO_PHOTOMETRY, oracle_depth, circle_deg=np.full(3, 185.0))
    difference = np.abs(got.pano.astype(float) - to_uint8(oracle).astype(float)).max(axis=-1)
    # Within a fisheye pixel of an image circle, along the sight lines or at infinity (the blind
    # spot's fallback), the oracle reads the black beyond it (see the test above).
    _, masks, theta = unwarp_grids(sample.rig.cameras, (256, 128), 185.0)
    pixel = 1.5 * 185.0 / 128
    edge = (masks & (92.5 - theta < pixel)).any(dim=0) | ((lines.theta <= 92.5) & (92.5 - lines.theta < pixel)).any(
        dim=0
    )
    assert difference[~edge.numpy()].max() <= 2 and difference[~edge.numpy()].mean() < 0.5
    rotation = psnr(rotation_only_stitch(sample.fisheyes, sample.rig, config)[0], sample.pano, lines.seen)
    assert psnr(_as_float(got.pano), sample.pano, lines.seen) > rotation + 3.0  # the parallax it removes


def _write_sample_project(folder, sample, width):
    names = tuple(f"camera{k}.png" for k in range(len(sample.fisheyes)))
    for name, fisheye in zip(names, sample.fisheyes):
        rigjax.write_image(folder / name, to_uint8(fisheye))
    sample.rig.project((width, width // 2), names).save(folder / "rig.pto")
    return folder / "rig.pto"


def test_a_given_inverse_depth_is_stitched_through(tmp_path, capsys):
    config, sample, _ = _tri_sample()
    path = _write_sample_project(tmp_path, sample, 256)
    truth = torch.where(torch.isfinite(sample.depth), 1.0 / sample.depth, torch.zeros_like(sample.depth))
    np.save(tmp_path / "inverse.npy", truth.numpy())
    assert (
        cli.main(
            [
                "stitch",
                "--rig",
                str(path),
                "-o",
                str(tmp_path / "pano.png"),
                "--inverse-depth",
                str(tmp_path / "inverse.npy"),
            ]
        )
        == 0
    )
    assert f"depth given: {tmp_path / 'inverse.npy'}" in capsys.readouterr().out
    got = _as_float(cv2.imread(str(tmp_path / "pano.png"))[..., ::-1].copy())
    seen = sight_lines(sample, config).seen
    through_truth = psnr(got, sample.pano, seen)
    swept = psnr(_as_float(stitch_project(path, 256, "sweep").stitched.pano), sample.pano, seen)
    rotation = psnr(rotation_only_stitch(sample.fisheyes, sample.rig, config)[0], sample.pano, seen)
    assert through_truth > swept + 1.0 and through_truth > rotation + 3.0, (through_truth, swept, rotation)
    # The same depth as an array, through the Python API: the same panorama.
    again = stitch_project(path, inverse_depth=truth.numpy().astype(np.float64)).stitched.pano
    np.testing.assert_array_equal(again, cv2.imread(str(tmp_path / "pano.png"))[..., ::-1])


def test_the_depth_a_stitch_was_rendered_at_is_written_and_stitched_through_again(tmp_path):
    # --depth d.npy writes the inverse depth each pixel was rendered at; given back as the depth
    # (without the occlusion test, which the working depth's render does not make, and without the
    # colour fit, which the given depth makes at its own reduction), the same panorama.
    _, sample, _ = _tri_sample()
    path = _write_sample_project(tmp_path, sample, 256)
    assert (
        cli.main(
            ["stitch", "--rig", str(path), "-o", str(tmp_path / "p.png"), "--sweep", "--depth", str(tmp_path / "d.npy")]
        )
        == 0
    )
    written = np.load(tmp_path / "d.npy")
    assert written.dtype == np.float32 and written.shape == (128, 256) and np.isfinite(written).all()
    assert (written >= 0).all() and written.max() > 0.5  # the scene's seam objects stand within 2 m
    clean = RenderConfig(photometry="none")
    first = stitch_project(path, 256, "sweep", config=clean, keep_depth=True).stitched
    again = stitch_project(
        path, inverse_depth=first.rendered_depth.numpy(), config=dataclasses.replace(clean, occlusion_tolerance=0.0)
    )
    np.testing.assert_array_equal(again.stitched.pano, first.pano)


def test_the_refinements_confidence_is_written_where_two_inputs_see_and_refused_where_nothing_is_refined(
    tmp_path, capsys
):
    config, sample, _ = _tri_sample()
    path = _write_sample_project(tmp_path, sample, 256)
    out = [str(tmp_path / "p.png"), "--sweep", "--confidence", str(tmp_path / "c.npy")]
    assert cli.main(["stitch", "--rig", str(path), "-o", *out]) == 0
    written = np.load(tmp_path / "c.npy")
    assert written.dtype == np.float32 and written.shape == (128, 256)
    assert written.min() >= 0.0 and written.max() <= 1.0
    # The truth's visibility: where one input alone sees a point (away from where two do, which the
    # working depth's errors may move) nothing was matched; where two or more do, some was.
    views = sight_lines(sample, config).visible.sum(dim=0).numpy()
    alone = (views == 1) & (F.max_pool2d(torch.from_numpy(views >= 2).float()[None], 9, 1, 4)[0].numpy() == 0)
    assert alone.sum() > 1000 and (written[alone] == 0).mean() > 0.99
    assert (written[views >= 2] > 0).mean() > 0.15 and written[views >= 2].mean() > 20 * written[alone].mean()

    def refused(*extra) -> str:
        assert cli.main(["stitch", "--rig", str(path), "-o", str(tmp_path / "q.png"), *extra]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and not (tmp_path / "q.png").exists(), err
        return err

    np.save(tmp_path / "d.npy", np.zeros((128, 256), np.float32))
    assert "--inverse-depth is stitched through as given" in refused(
        "--inverse-depth", str(tmp_path / "d.npy"), "--confidence", str(tmp_path / "c2.npy")
    )
    assert "written as a .npy array" in refused("--confidence", str(tmp_path / "c.png"))
    with pytest.raises(ConfigError, match="does not refine its depth"):
        stitch_project(path, 256, "sweep", config=RenderConfig(refine_levels=0), confidence=True)


def test_render_settings_are_replaced_from_the_command_line_and_bad_ones_refused_naming_the_key(tmp_path, capsys):
    _, sample, _ = _tri_sample()
    path = _write_sample_project(tmp_path, sample, 256)
    base = ["stitch", "--rig", str(path), "--sweep", "-o"]
    assert cli.main([*base, str(tmp_path / "refined.png")]) == 0
    assert "refine " in capsys.readouterr().out  # the stage's time in the summary
    assert cli.main([*base, str(tmp_path / "coarse.png"), "--render", "refine_levels=0", "photometry=none"]) == 0
    assert "refine " not in capsys.readouterr().out
    coarse = cv2.imread(str(tmp_path / "coarse.png"))[..., ::-1]
    expected = stitch_project(path, 256, "sweep", config=RenderConfig(refine_levels=0, photometry="none")).stitched
    np.testing.assert_array_equal(coarse, expected.pano)
    for bad, named in (("refine_levels=-1", "refine_levels"), ("refine_level=2", "refine_level"), ("x", "'x'")):
        assert cli.main([*base, str(tmp_path / "bad.png"), "--render", bad]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and named in err and not (tmp_path / "bad.png").exists(), err


def test_a_given_inverse_depth_that_cannot_be_stitched_through_is_refused_in_one_line(tmp_path, capsys):
    _, sample, _ = _tri_sample()
    path = _write_sample_project(tmp_path, sample, 256)
    depth = tmp_path / "inverse.npy"

    def refused(values, *extra) -> str:
        if values is not None:
            np.save(depth, values)
        assert (
            cli.main(
                ["stitch", "--rig", str(path), "-o", str(tmp_path / "p.png"), "--inverse-depth", str(depth), *extra]
            )
            == 2
        )
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and not (tmp_path / "p.png").exists(), err
        return err

    assert "inverse.npy: an inverse depth 128 x 64, the panorama 256 x 128" in refused(np.zeros((64, 128), np.float32))
    assert "the panorama 512 x 256" in refused(np.zeros((128, 256), np.float32), "--width", "512")
    spoilt = np.zeros((128, 256), np.float32)
    spoilt[5, 7], spoilt[9, 1] = np.nan, -0.5
    assert (
        "inverse.npy: 2 inverse depths are not finite (as float32) or below 0 (the first at row 5, column 7"
        in refused(spoilt)
    )
    spoilt = np.zeros((128, 256))
    spoilt[3, 4] = 1e300  # finite in float64, not in the float32 the stitch reads
    assert (
        "inverse.npy: 1 inverse depths are not finite (as float32) or below 0 (the first at row 3, column 4"
        in refused(spoilt)
    )
    depth.write_text("not an array")
    assert "inverse.npy: not a .npy array of inverse depths" in refused(None)
    with open(depth, "wb") as f:
        np.savez(f, depth=np.zeros((128, 256)))
    assert "inverse.npy: an .npz archive; give the inverse depth as one .npy array" in refused(None)
    depth.unlink()
    assert "inverse.npy: cannot read it (No such file or directory)" in refused(None)
    np.save(depth, np.zeros((128, 256), np.float32))
    path.write_text("\n".join(line for line in path.read_text().splitlines() if "centre" not in line) + "\n")
    assert "gives no camera centres" in refused(None)


def test_fed_the_true_depth_alone_an_input_whose_sight_line_meets_an_occluder_is_not_blended():
    # The scene's seam objects stand in front of the street: a camera whose line to a point meets one
    # first (ray cast in the scene: the true visibility) images the object there, not the point.
    config, sample, rig = _tri_sample()
    lines = sight_lines(sample, config)
    oracle = to_uint8(
        depth_oracle_stitch(
            sample.fisheyes, lines, config, rotation_only_stitch(sample.fisheyes, sample.rig, config)[0]
        )
    ).astype(float)
    inverse_depth = torch.where(torch.isfinite(sample.depth), 1.0 / sample.depth, torch.zeros_like(sample.depth))
    blocked = (lines.theta <= 92.5) & ~lines.visible & torch.isfinite(sample.depth)[None]  # in its circle, hidden
    blocked &= lines.visible.any(dim=0)[None]  # and another camera sees the point
    tested = unoccluded(torch.as_tensor(rig.centres, dtype=torch.float32), inverse_depth, 0.5, 0.1, 32)
    assert (blocked & ~tested).sum() >= 0.85 * blocked.sum() and blocked.sum() > 300
    assert (lines.visible & ~tested).sum() <= 0.05 * lines.visible.sum()  # what it sees, it is left to see
    occluded = blocked.any(dim=0).numpy()
    given = GivenDepth(full=inverse_depth)
    circles = np.full(3, 185.0)
    got = stitch_rig(rig, 256, NO_PHOTOMETRY, given, circle_deg=circles).pano.astype(float)
    untested = dataclasses.replace(NO_PHOTOMETRY, occlusion_tolerance=0.0)
    blended = stitch_rig(rig, 256, untested, given, circle_deg=circles).pano.astype(float)
    error, before = (np.abs(pano - oracle).max(axis=-1)[occluded].mean() for pano in (got, blended))
    assert error < 0.4 * before, (error, before)
    seen = lines.seen
    assert psnr(_as_float(got.astype(np.uint8)), sample.pano, seen) > psnr(
        _as_float(blended.astype(np.uint8)), sample.pano, seen
    )


def test_pyramid_levels_made_from_finer_ones_are_the_box_means_of_the_full_image():
    """A frame's inputs at the levels of several working widths (learnstitch.fullres.stitcher.Frame):
    each later level is shrunk from the nearest finer one made; the same as the full image's box
    means (torch's avg_pool2d), odd sizes' remainders dropped."""
    from types import SimpleNamespace

    image = torch.from_numpy(np.random.default_rng(0).random((517, 389, 3), dtype=np.float32)).permute(2, 0, 1)
    tables, pyramid = SimpleNamespace(focal=torch.tensor([1000.0])), [{}]
    # 2 pi 1000 / 2^L pixels around: a canvas whose pixels are level L's
    for width, level in ((1570, 2), (392, 4), (786, 3)):
        [(shrunk, factor)] = working_images([image], tables, width, pyramid)
        assert factor == 2.0**level and pyramid[0][level] is shrunk
        want = F.avg_pool2d(image[None], 2**level)[0]
        assert shrunk.shape == want.shape
        torch.testing.assert_close(shrunk, want, rtol=0, atol=1e-6)
    assert sorted(pyramid[0]) == [2, 3, 4]


def test_the_projects_photometry_is_undone_before_the_stitch():
    """Each camera photographed through Hugin's gains (vignetting down to about -1 stop at the image
    circle, an exposure value and a white balance of its own; written here from Hugin's formula): with
    its i line's values the stitch is the clean images' stitch, to the 8-bit rounding."""
    _, _, rig = _tri_sample()
    images, photographed, gains = [], [], []
    for k, pixels in enumerate(rig.images):
        h, w = pixels.shape[:2]
        line = rigjax.Image(
            w,
            h,
            3,
            exposure_value=0.2 * k,
            white_balance_red=1.0 - 0.05 * k,
            white_balance_blue=0.9,
            vignetting_b=-0.8,
            vignetting_c=-0.4,
            vignetting_d=0.1,
            vignetting_x=3.0 * k,
        )
        y, x = np.mgrid[:h, :w].astype(float)
        r2 = ((x - (w - 1) / 2 - 3.0 * k) ** 2 + (y - (h - 1) / 2) ** 2) / ((w / 2) ** 2 + (h / 2) ** 2)
        gain = (1 - 0.8 * r2 - 0.4 * r2**2 + 0.1 * r2**3) * 2 ** (-0.2 * k)
        gain = gain[..., None] * np.array([1.0 - 0.05 * k, 1.0, 0.9])
        images.append(line)
        photographed.append(np.round(pixels * gain).astype(np.uint8))
        gains.append(gain)
    undo = photometry_undone(rigjax.Project.new(rigjax.PanoramaLine(256, 128), images))
    for k, factor in enumerate(undo):  # Hugin's gains inverted (where V(r) is not cut off at 0.05, in the corners)
        inside = gains[k].min(axis=-1) > 0.1
        np.testing.assert_allclose(factor[inside], 1.0 / gains[k][inside], rtol=1e-5)
        read = float_images([photographed[k]], [factor])[0].permute(1, 2, 0).numpy()  # each pixel's colours
        np.testing.assert_allclose(read[inside], (photographed[k] / 255.0 / gains[k])[inside], rtol=1e-5, atol=1e-7)
    # Exposures as Hugin reads them from a camera's EXIF, 10 stops up, the panorama's E with them: the same
    brighter = [image.replace(exposure_value=image.exposure_value + 10.0) for image in images]
    same = photometry_undone(rigjax.Project.new(rigjax.PanoramaLine(256, 128, exposure_value=10.0), brighter))
    for factor, factor_10 in zip(undo, same):
        np.testing.assert_allclose(factor_10, factor, rtol=1e-6)
    circles = dict(circle_deg=np.full(3, 185.0))
    clean = stitch_rig(rig, 256, NO_PHOTOMETRY, **circles).pano.astype(float)
    got = stitch_rig(rig._replace(images=photographed, undo=undo), 256, NO_PHOTOMETRY, **circles).pano.astype(float)
    kept = stitch_rig(rig._replace(images=photographed), 256, NO_PHOTOMETRY, **circles).pano.astype(float)
    seen = clean.max(axis=-1) > 0
    assert np.abs(got - clean)[seen].mean() < 0.5 and np.percentile(np.abs(got - clean)[seen], 99) <= 3
    assert np.abs(kept - clean)[seen].mean() > 10  # the gains, not undone (measured: 0.26 and 24.3 levels)
    assert (
        photometry_undone(
            rigjax.Project.new(
                rigjax.PanoramaLine(256, 128),
                [
                    images[0].replace(
                        vignetting_b=0.0,
                        vignetting_c=0.0,
                        vignetting_d=0.0,
                        white_balance_red=1.0,
                        white_balance_blue=1.0,
                        vignetting_x=0.0,
                    )
                ]
                * 2,
            )
        )
        is None
    )


def test_permuting_the_inputs_changes_nothing():
    _, _, rig = _tri_sample()
    first = stitch_rig(rig, 256, RenderConfig(working_width=128), circle_deg=np.full(3, 185.0))
    again = stitch_rig(rig.permuted([2, 0, 1]), 256, RenderConfig(working_width=128), circle_deg=np.full(3, 185.0))
    assert first.inverse_depth.any()
    torch.testing.assert_close(first.inverse_depth, again.inverse_depth)
    torch.testing.assert_close(first.exposure[[2, 0, 1]], again.exposure, atol=1e-5, rtol=0)
    assert np.abs(first.pano.astype(int) - again.pano.astype(int)).max() <= 1


# Rigs of 2, 3, 4 and 6 cameras and several lenses, each rendered from an environment at infinity
# with its cameras 5 cm from the centre; the panorama must be that environment wherever a camera sees.
RIGS = {
    "dual 190-degree fisheyes": dict(
        orientations=[(0, 0, 0), (180, 0, 0)], projection=2, width=200, height=200, hfov=190, b=0.0
    ),
    "three 185-degree fisheyes": dict(
        orientations=[(0, 0, 0), (120, 0, 0), (-120, 0, 0)], projection=2, width=160, height=160, hfov=185, b=0.0
    ),
    "a ring of four full-frame fisheyes": dict(
        orientations=[(0, 0, 0), (90, 0, 0), (180, 0, 0), (-90, 0, 0)],
        projection=3,
        width=200,
        height=150,
        hfov=150,
        b=-0.01,
    ),
    "a cube of six rectilinear cameras": dict(
        orientations=[(0, 0, 0), (90, 0, 0), (180, 0, 0), (-90, 0, 0), (0, 90, 0), (0, -90, 0)],
        projection=0,
        width=160,
        height=160,
        hfov=100,
        b=0.0,
    ),
}


def _write_rig(folder, spec, environment, centres=True):
    project = rig_from_orientations(
        spec["orientations"],
        pano_width=512,
        orientation_jitter_deg=2.0,
        seed=3,
        **{k: v for k, v in spec.items() if k != "orientations"},
    )
    for k, pixels in enumerate(render_images(project, environment)):
        rigjax.write_image(folder / project.images[k].filename, pixels)
    if centres:
        axes = np.asarray(project.cameras().world_from_cam)[:, :, 2]
        project = project.replace(centres=0.05 * axes)
    project.save(folder / "rig.pto")
    return folder / "rig.pto"


@pytest.fixture(scope="module")
def environment():
    return procedural_environment(1024, seed=2)


@pytest.mark.parametrize("name", RIGS)
def test_rigs_of_any_camera_count_and_lens_stitch_the_scene(tmp_path, environment, name):
    path = _write_rig(tmp_path, RIGS[name], environment)
    done = stitch_project(path, 256, "sweep")
    assert len(done.rig.images) == len(RIGS[name]["orientations"]) and done.notes == ["depth from the plane sweep"]
    truth = cv2.resize(environment, (256, 128), interpolation=cv2.INTER_AREA)
    covered = torch.as_tensor(done.stitched.covered)
    assert covered.float().mean() > 0.6
    assert psnr(_as_float(done.stitched.pano), _as_float(truth), covered) > 27.0
    assert not done.stitched.pano[~done.stitched.covered].any()


def test_cli_stitches_a_rig_and_writes_its_depth(tmp_path, environment, capsys):
    path = _write_rig(tmp_path, RIGS["three 185-degree fisheyes"], environment, centres=False)
    assert (
        cli.main(["stitch", "--rig", str(path), "-o", str(tmp_path / "pano.png"), "--depth", str(tmp_path / "d.png")])
        == 0
    )
    out = capsys.readouterr().out
    assert "gives no camera centres (#-rigjax centre lines): a rotation-only stitch" in out
    assert "pano.png: 512 x 256 panorama of 3 cameras" in out
    written = cv2.imread(str(tmp_path / "pano.png"))[..., ::-1]
    np.testing.assert_array_equal(written, stitch_project(path).stitched.pano)
    assert cv2.imread(str(tmp_path / "d.png")).shape == (256, 512, 3)


def test_bad_rigs_are_refused_naming_the_project_and_the_image(tmp_path, environment):
    path = _write_rig(tmp_path, RIGS["dual 190-degree fisheyes"], environment)
    text = path.read_text()
    lines = text.splitlines()
    number = next(n for n, line in enumerate(lines, start=1) if line.startswith("i "))  # image 0's i line
    (tmp_path / "one.pto").write_text('p f2 w512 h256 v360\ni w200 h200 f2 v190 n"cam0.png"\n')
    with pytest.raises(ConfigError, match=r"one.pto: 1 image; stitching needs at least 2 cameras"):
        load_rig(tmp_path / "one.pto")
    (tmp_path / "missing.pto").write_text(text.replace('n"cam0.png"', 'n"gone.png"'))
    with pytest.raises(ImageError, match=rf"missing.pto:{number} \(image 0\): .*gone.png: no such image file"):
        load_rig(tmp_path / "missing.pto")
    (tmp_path / "small.png").write_bytes((tmp_path / "cam0.png").read_bytes())
    rigjax.write_image(tmp_path / "small.png", np.zeros((100, 120, 3), np.uint8))
    (tmp_path / "size.pto").write_text(text.replace('n"cam0.png"', 'n"small.png"'))
    with pytest.raises(
        ImageError, match=rf"small.png: 120 x 100 pixels, but .*size.pto:{number} \(image 0\) is 200 x 200"
    ):
        load_rig(tmp_path / "size.pto")
    (tmp_path / "lens.pto").write_text(text.replace("i w200 h200 f2", "i w200 h200 f7", 1))
    with pytest.raises(rigjax.RigjaxError, match=r"lens.pto"):
        load_rig(tmp_path / "lens.pto")
    with pytest.raises(ConfigError, match=r"has 2 images, 3 were given"):
        load_rig(path, [np.zeros((200, 200, 3), np.uint8)] * 3)
    # A crop: a circular fisheye's is honoured, another lens's only where it holds the whole frame.
    as_f3 = text.replace("i w200 h200 f2", "i w200 h200 f3", 1)
    (tmp_path / "frame_crop.pto").write_text(as_f3.replace('n"cam0.png"', 'S0,200,-1,201 n"cam0.png"'))
    assert load_rig(tmp_path / "frame_crop.pto").crops == (None, None)
    (tmp_path / "inner_crop.pto").write_text(as_f3.replace('n"cam0.png"', 'S10,190,0,200 n"cam0.png"'))
    with pytest.raises(ConfigError, match=r"inner_crop.pto, image 0: a crop \(S\) inside the frame is honoured on"):
        load_rig(tmp_path / "inner_crop.pto")
    (tmp_path / "circle_crop.pto").write_text(text.replace('n"cam0.png"', 'S10,190,10,190 n"cam0.png"'))
    assert load_rig(tmp_path / "circle_crop.pto").crops == ((10, 190, 10, 190), None)
    with pytest.raises(ConfigError, match=r"2 cameras, but .* stitches rigs of 3"):
        stitch_project(path, model=SHIPPED_MODEL)


def test_render_settings_are_a_config_section_whose_bad_values_are_named():
    from learnstitch.config import config_from_dict

    assert config_from_dict({"render": {"working_width": 256}}, "x.yaml").render.working_width == 256
    with pytest.raises(ConfigError, match=r"x.yaml: render: photometry must be 'fitted' or 'none', got 'maps'"):
        config_from_dict({"render": {"photometry": "maps"}}, "x.yaml")
    with pytest.raises(ConfigError, match=r"render: unknown key 'width'"):
        config_from_dict({"render": {"width": 4096}}, "x.yaml")
    with pytest.raises(ConfigError, match=r"x.yaml: render: blend must be 'feather' or 'network', got 'mean'"):
        config_from_dict({"render": {"blend": "mean"}}, "x.yaml")


def test_the_full_resolution_demo_stitches_its_rig_from_disk(tmp_path, capsys):
    """`make demo`'s full-resolution step, at 128 pixels: the network's depth beats the true-rotation
    stitch and the depth oracle beats both; its rig re-stitched from the files it wrote is the same."""
    assert cli.main(["demo", "--fullres", "128", "--out", str(tmp_path)]) == 0
    rows = [line for line in capsys.readouterr().out.splitlines() if " dB " in line]
    network, rotation, oracle = ([float(v) for v in line.split("dB")[0].split("/")] for line in rows)
    assert oracle[1] > network[1] > rotation[1] + 1.0
    again = stitch_project(tmp_path / "rig.pto").stitched.pano
    np.testing.assert_array_equal(again, cv2.imread(str(tmp_path / "network.png"))[..., ::-1])


def test_a_fisheyes_circle_is_measured_from_where_its_content_ends(environment):
    # An equidistant fisheye (focal f px per radian) whose content ends 80 px from the centre, well
    # inside the circle its hfov would draw: the circle's radius is 80.5 px (the last pixel's outer
    # edge), its half-angle 80.5 / f radians, in closed form.
    project = rig_from_orientations([(0, 0, 0), (180, 0, 0)], projection=2, width=200, height=200, hfov=190, b=0.0)
    pixels = render_images(project, environment)
    y, x = np.mgrid[0:200, 0:200]
    pixels[0][np.hypot(x - 99.5, y - 99.5) > 80.0] = 0
    cameras = project.cameras(host=True)
    radii = list(image_circles_px(project, pixels))
    assert radii[0] == pytest.approx(80.5, abs=0.6)
    assert radii[1] > 99.0  # content to the frame's edge
    focal = 200 / np.radians(190.0)
    tables = sight_tables(cameras, np.zeros((2, 3)), 1024, circle_px=np.array(radii))
    assert float(tables.half_deg[0]) == pytest.approx(np.degrees(radii[0] / focal), abs=0.05)
    assert float(tables.half_deg[1]) == pytest.approx(95.0)  # at most the hfov's circle
    assert np.isnan(image_circle_px(0, 0.0, 0.0, pixels[0]))  # a rectilinear lens: its frame bounds it


@pytest.mark.parametrize("crop", [None, (40, 300, 10, 250)])
def test_the_circle_is_the_content_radii_quantile_written_plainly(crop):
    # Against the rule written the plain way (every content pixel's distance, numpy's quantile):
    # a disc of content off the image's centre, stray bright pixels beyond it, a lens shifted.
    rng = np.random.default_rng(3)
    pixels = np.zeros((260, 340, 3), np.uint8)
    y, x = np.mgrid[0:260, 0:340]
    pixels[np.hypot(x - 171.25, y - 127.5) < 117.3] = 200
    pixels[rng.integers(0, 260, 40), rng.integers(0, 340, 40), rng.integers(0, 3, 40)] = 255
    d, e = 1.5, -2.0
    ys, xs = np.nonzero(pixels.max(axis=-1) > 24)
    if crop is not None:
        inside = np.hypot(xs - 170.0, ys - 130.0) <= 120.0  # the crop's circle, Hugin's rule
        xs, ys = xs[inside], ys[inside]
    plain = np.quantile(np.hypot(xs - (170 - 0.5 + d), ys - (130 - 0.5 + e)), 0.9995) + 0.5
    assert image_circle_px(2, d, e, pixels, crop) == pytest.approx(plain, rel=1e-12)


@pytest.mark.parametrize("size, d", [(2, 0.0), (3, 0.0), (7, 0.5), (64, 0.25)])
def test_a_frame_full_of_content_is_measured_by_the_same_rule(size, d):
    # Content in every pixel: the two order statistics the rule reads sit in the frame's corners,
    # and in a frame of 2 or 3 pixels the lattice holds more pixels near the centre than the area
    # of the disc the measurement passes over.
    pixels = np.full((size, size, 3), 90, np.uint8)
    ys, xs = np.mgrid[0:size, 0:size]
    centre = size / 2 - 0.5 + d
    plain = np.quantile(np.hypot(xs - centre, ys - centre).ravel(), 0.9995) + 0.5
    assert image_circle_px(2, d, d, pixels) == pytest.approx(plain, rel=1e-12)


def test_a_crop_keeps_each_camera_inside_its_circle_off_the_lens_axis():
    # A circular fisheye whose crop circle (Hugin's S: centred at ((l + r) / 2, (t + b) / 2), of half
    # the shorter side) sits 15 px right of and 10 px above its distortion centre: a direction is
    # seen where rigjax maps it inside that circle less the sqrt 2 px a bilinear sample reaches out.
    project = rig_from_orientations([(0, 0, 0), (180, 0, 0)], projection=2, width=200, height=200, hfov=200, b=0.0)
    crop = (35, 195, 10, 170)  # centre (115, 90), radius 80: the lens's centre is (99.5, 99.5)
    cameras = project.cameras(host=True)
    tables = sight_tables(cameras, np.zeros((2, 3)), 1024, crops=[crop, None])
    rays = torch.nn.functional.normalize(torch.randn(20000, 3, generator=torch.Generator().manual_seed(0)), dim=-1)
    seen = views(tables, rays, torch.zeros(len(rays)))
    xy, ok = rigjax.ray_to_img(project.cameras().take(0), rays.double().numpy())
    inside = np.hypot(np.asarray(xy)[:, 0] - 115.0, np.asarray(xy)[:, 1] - 90.0)
    visible = seen.visible[0].numpy()
    assert visible.sum() > 2000 and np.asarray(ok)[visible].all()
    assert inside[visible].max() <= 80.0 - np.sqrt(2.0) + 0.01  # the tables' interpolation, a hundredth of a pixel
    clear = (
        np.asarray(ok) & (inside < 80.0 - np.sqrt(2.0) - 0.01) & (np.asarray(xy)[:, 0] > 1) & (np.asarray(xy)[:, 1] > 1)
    )
    assert visible[clear].all()
    assert seen.feather[0][visible].min() >= 0.0 and (seen.feather[0][~torch.from_numpy(visible)] == 0).all()
    # No crop: the frame and the lens's circle bound it, as before.
    alone = views(sight_tables(cameras, np.zeros((2, 3)), 1024), rays, torch.zeros(len(rays)))
    assert torch.equal(seen.visible[1], alone.visible[1]) and torch.equal(seen.feather[1], alone.feather[1])
    # A pyramid level's samples reach further: the crop's inset grows as the circle's does.
    shrunk = views(tables, rays, torch.zeros(len(rays)), scales=torch.tensor([4.0, 1.0]))
    assert inside[shrunk.visible[0].numpy()].max() <= 80.0 - 6 * np.sqrt(2.0) + 0.01


def test_blending_by_the_network_weighs_each_input_by_its_share(tmp_path, environment):
    # The network gives camera 0 the whole blend: wherever it sees, the panorama is camera 0's alone,
    # as the oracle's renderer draws it when told that only camera 0 sees there.
    rig = load_rig(_write_rig(tmp_path, RIGS["dual 190-degree fisheyes"], environment))
    shares = torch.stack([torch.ones(32, 64), torch.zeros(32, 64)])
    config = RenderConfig(photometry="none", blend="network")
    blended = stitch_rig(rig, 256, config, GivenDepth(torch.zeros(32, 64), shares=shares))
    visibility = torch.stack([torch.ones(128, 256), torch.zeros(128, 256)])
    alone = stitch_rig(rig, 256, config, GivenDepth(full=torch.zeros(128, 256), visibility=visibility))
    difference = np.abs(blended.pano.astype(int) - alone.pano.astype(int))
    assert difference.max() <= 2
    feathered = stitch_rig(rig, 256, RenderConfig(photometry="none"), GivenDepth(torch.zeros(32, 64)))
    assert np.abs(feathered.pano.astype(int) - alone.pano.astype(int)).max() > 10  # the seam differs without it


@pytest.fixture(scope="module")
def any_rig_checkpoint(tmp_path_factory):
    """An untrained network of any rig (model.pooling: pooled): its depth is the matching cost's
    least plane, with the far prior where there is none."""
    from test_anyrig import POOLED as model

    from learnstitch.checkpoint import CHECKPOINT_FORMAT, save_checkpoint
    from learnstitch.config import StitchConfig, config_as_dict
    from learnstitch.network import build_model

    data = SynthConfig(pano_width=128, rig="random")
    torch.manual_seed(0)
    path = tmp_path_factory.mktemp("any_rig") / "model.pt"
    config = config_as_dict(StitchConfig(data=data, model=model, name="any_rig"))
    state = {"format": CHECKPOINT_FORMAT, "config": config, "model": build_model(model, data).state_dict()}
    save_checkpoint(path, state)
    return path


@pytest.mark.parametrize("name", RIGS)
def test_one_network_of_any_rig_stitches_every_camera_count(tmp_path, environment, any_rig_checkpoint, name):
    path = _write_rig(tmp_path, RIGS[name], environment)
    done = stitch_project(path, 256, any_rig_checkpoint)
    assert done.notes == ["depth from the rig-aware network model.pt"]
    assert done.stitched.inverse_depth.shape == (64, 128)  # the network's own canvas
    truth = cv2.resize(environment, (256, 128), interpolation=cv2.INTER_AREA)
    covered = torch.as_tensor(done.stitched.covered)
    assert psnr(_as_float(done.stitched.pano), _as_float(truth), covered) > 27.0


def test_a_stitcher_prepared_once_stitches_each_frame_as_a_fresh_stitch_would(tmp_path, environment, monkeypatch):
    # Two frames of one rig: the second the first turned 30 degrees (its scene moved). The prepared
    # stitcher makes the sight tables once, and each frame comes out as the one-call stitch of that
    # frame's images gives it.
    import learnstitch.fullres.stitcher as stitcher_module

    path = _write_rig(tmp_path, RIGS["three 185-degree fisheyes"], environment)
    rig = load_rig(path)
    second = [np.ascontiguousarray(np.roll(image, 17, axis=1)) for image in rig.images]
    made = []
    monkeypatch.setattr(stitcher_module, "sight_tables", lambda *a, **k: made.append(1) or sight_tables(*a, **k))
    stitcher = Stitcher.prepare(rig, 256, RenderConfig(working_width=128))
    frames = [stitcher(rig.images), stitcher(second)]
    assert len(made) == 1
    for images, got in zip((rig.images, second), frames):
        fresh = stitch_rig(rig._replace(images=images), 256, RenderConfig(working_width=128))
        np.testing.assert_array_equal(got.pano, fresh.pano)
        torch.testing.assert_close(got.inverse_depth, fresh.inverse_depth, rtol=0, atol=0)
    assert np.abs(frames[0].pano.astype(int) - frames[1].pano.astype(int)).mean() > 5  # they are other frames
    assert set(frames[1].seconds) == {"depth", "photometry", "refine", "render"} and set(stitcher.seconds) == {"tables"}


def test_a_stitcher_refuses_a_frame_that_is_not_its_rigs_naming_the_image(tmp_path, environment):
    rig = load_rig(_write_rig(tmp_path, RIGS["dual 190-degree fisheyes"], environment))
    stitcher = Stitcher.prepare(rig, 64)
    with pytest.raises(ConfigError, match=r"the rig has 2 cameras, 3 images were given"):
        stitcher([rig.images[0]] * 3)
    with pytest.raises(ConfigError, match=r"cam1.png: expected a 200 x 200 uint8 RGB image, got uint8 \(100, 200, 3\)"):
        stitcher([rig.images[0], rig.images[1][:100]])
    with pytest.raises(ConfigError, match=r"a working-size depth or a full-size one"):
        GivenDepth()
    with pytest.raises(ConfigError, match=r"visibility goes with a full-size depth"):
        GivenDepth(torch.zeros(8, 16), visibility=torch.ones(2, 64, 128))
    with pytest.raises(ConfigError, match=r"shares go with a working-size depth"):
        GivenDepth(full=torch.zeros(64, 128), shares=torch.ones(2, 8, 16))
