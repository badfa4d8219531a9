"""``rigjax calibrate --start rig.pto``: a project made before (Hugin's form of a dual-fisheye
template: every ``i`` line the whole side-by-side frame, each lens kept to its half by its crop) as
the rig the calibration starts from."""

import subprocess

import jax
import numpy as np
import pytest

jax.config.update("jax_enable_x64", True)

import rigjax
from rigjax import cli, synthetic
from rigjax.calibration.stages import nominal_project
from rigjax.calibration.start import cut_image, with_start
from rigjax.camera.lenses import focal_length, hfov_from_focal
from rigjax.camera.model import map_points
from rigjax.camera.photometry import vignetting

TEMPLATE = "configs/rig/dual_fisheye_far.yaml"
# A whole side-by-side frame's hfov per lens type (each half then sees half its width)
WHOLE_HFOV = {2: 390.0, 3: 390.0, 21: 300.0, 10: 300.0, 0: 120.0, 8: 150.0}


def _whole_frame_project(projection: int, width: int = 1200, height: int = 600) -> rigjax.Project:
    """Two lenses in one ``width`` x ``height`` frame as Hugin's templates state them: each ``i`` line
    the whole frame, its lens's centre shifted to its half (``d`` about a quarter of the width),
    cropped to its half's circle, with distortion and a vignetting centre off the image's."""
    images = []
    for k, (yaw, sign) in enumerate([(0.0, -1), (180.0, 1)]):
        half = width / 4
        images.append(
            rigjax.Image(
                width=width,
                height=height,
                projection=projection,
                hfov=WHOLE_HFOV[projection] - 3.0 * k,
                a=-0.02,
                b=0.03 - 0.01 * k,
                c=-0.01,
                d=sign * half + 7.0 - 11.0 * k,
                e=-9.0 + 13.0 * k,
                yaw=yaw,
                pitch=0.6 * k,
                roll=-0.4 * k,
                vignetting_b=-0.3,
                vignetting_c=0.05,
                vignetting_d=-0.02,
                vignetting_x=sign * half + 3.0,
                vignetting_y=-2.0,
                crop=(int(k * width / 2 - 5), int((k + 1) * width / 2 + 5), -4, height + 4),
                filename="frame.jpg",
            )
        )
    return rigjax.Project.new(rigjax.PanoramaLine(2048, 1024), images)


def _halves(project: rigjax.Project) -> list[rigjax.Image]:
    return [
        cut_image(image, k * image.width // 2, 0, image.width // 2, image.height)
        for k, image in enumerate(project.images)
    ]


def _points_in_half(image: rigjax.Image, rng) -> np.ndarray:
    """Pixels of a half, in its own coordinates, within 80 % of its circle."""
    half_w, height = image.width // 2, image.height
    angle, radius = rng.uniform(0, 2 * np.pi, 400), 0.4 * min(half_w, height) * np.sqrt(rng.uniform(0, 1, 400))
    return np.stack([half_w / 2 + radius * np.cos(angle), height / 2 + radius * np.sin(angle)], -1)


def test_hfov_from_focal_inverts_the_focal_length():
    for projection, hfov in WHOLE_HFOV.items():
        hfov = min(hfov, 170.0) if projection in (0, 8) else hfov
        focal = float(focal_length(projection, 1000, hfov))
        assert hfov_from_focal(projection, 1000, focal) == pytest.approx(hfov, rel=1e-12)
    with pytest.raises(ValueError, match="no f8 lens of focal length"):
        hfov_from_focal(8, 3000, 1000.0)


@pytest.mark.parametrize("projection", sorted(WHOLE_HFOV))
def test_a_half_cut_from_the_whole_frame_sees_the_same_rays_and_vignetting(projection):
    whole = _whole_frame_project(projection)
    halves = rigjax.Project.new(whole.panorama, _halves(whole))
    rng = np.random.default_rng(projection)
    for k in range(2):
        xy = _points_in_half(whole.images[k], rng)
        offset = np.array([k * whole.images[k].width // 2, 0.0])
        ray_whole, ok_whole = map_points(rigjax.img_to_ray, whole.cameras().take(k), xy + offset)
        ray_half, ok_half = map_points(rigjax.img_to_ray, halves.cameras().take(k), xy)
        assert ok_whole.all() and ok_half.all()
        np.testing.assert_allclose(ray_half, ray_whole, atol=1e-11)
        np.testing.assert_allclose(
            vignetting(halves.images[k], xy), vignetting(whole.images[k], xy + offset), rtol=1e-12
        )
    # The crop moves with the half: each half's crop circle is where the whole frame's was.
    assert halves.images[1].crop == (-5, 605, -4, 604)


@pytest.mark.hugin
@pytest.mark.parametrize("projection", [2, 3, 21, 0])
def test_a_half_maps_where_hugin_maps_the_whole_frame(projection, hugin_tools, tmp_path):
    """pano_trafo: a pixel of a half lands on the panorama where the same pixel of the whole frame does."""
    whole = _whole_frame_project(projection)
    whole.save(tmp_path / "whole.pto")
    rigjax.Project.new(whole.panorama, _halves(whole)).save(tmp_path / "halves.pto")
    rng = np.random.default_rng(7)
    image = np.repeat([0, 1], 200)
    xy = np.concatenate([_points_in_half(whole.images[k], rng)[:200] for k in range(2)])
    offset = np.stack([image * (whole.images[0].width // 2), np.zeros(len(image))], -1)

    def trafo(name, points):
        text = "".join(f"{k} {x:.9f} {y:.9f}\n" for k, (x, y) in zip(image, points))
        out = subprocess.run(
            ["pano_trafo", str(tmp_path / name)], input=text, capture_output=True, text=True, check=True
        )
        return np.array([[float(v) for v in line.split()] for line in out.stdout.split("\n")[: len(image)]])

    # libpano13 stops its distortion's Newton solve at 1e-6 of the radius (about 3e-4 px here)
    np.testing.assert_allclose(trafo("halves.pto", xy), trafo("whole.pto", xy + offset), atol=2e-3)


def test_a_cut_that_changes_the_distortions_radius_is_refused():
    image = _whole_frame_project(2).images[0]
    with pytest.raises(rigjax.RigjaxError, match="changes the radius that normalises its distortion"):
        cut_image(image, 0, 0, 600, 500)
    # Without distortion, any cut is the same camera.
    plain = image.replace(a=0.0, b=0.0, c=0.0)
    assert cut_image(plain, 0, 0, 600, 500).height == 500


def test_with_start_takes_the_projects_lenses_orientations_and_crops():
    config = rigjax.load_template(TEMPLATE)
    whole = _whole_frame_project(2)
    started = with_start(config, whole, (600, 600), source="gear.pto")
    halves = _halves(whole)
    assert not started.rig.shared_lens  # the project's lenses are not linked
    assert started.rig.orientations == ((0.0, 0.0, 0.0), (180.0, 0.6, -0.4))
    nominal = nominal_project(started, [(600, 600)] * 2, ["a-left.png", "a-right.png"])
    for got, want in zip(nominal.images, halves):
        for letter in ("v", "a", "b", "c", "d", "e", "y", "p", "r"):
            assert got.value(letter) == want.value(letter)
        assert got.crop == want.crop
    # Hugin's vignetting of each lens comes along, in the half's pixels.
    for got, want in zip(nominal.images, halves):
        for letter in ("Vb", "Vc", "Vd", "Vx", "Vy"):
            assert got.value(letter) == want.value(letter)
    # The right lens listed first: each image is the camera of the half its crop is in.
    swapped = with_start(config, whole.replace(images=whole.images[::-1]), (600, 600), source="gear.pto")
    assert swapped.rig.lenses == started.rig.lenses and swapped.rig.orientations == started.rig.orientations
    with pytest.raises(rigjax.RigjaxError, match=r"gear.pto: images 0 and 1 .* are both the left half"):
        with_start(config, whole.replace(images=(whole.images[0],) * 2), (600, 600), source="gear.pto")
    # A project of halves is taken as it is; a linked one is one lens.
    linked = rigjax.Project.new(
        whole.panorama,
        [
            halves[0],
            halves[1].replace(
                hfov=halves[0].hfov, a=halves[0].a, b=halves[0].b, c=halves[0].c, links=dict.fromkeys("vabc", 0)
            ),
        ],
    )
    assert with_start(config, linked, (600, 600)).rig.shared_lens
    # Bad starts name the project, the image and both sizes.
    with pytest.raises(
        rigjax.RigjaxError, match=r"gear.pto, image 0: it is 1200x600, but the calibrated images are 640x640"
    ):
        with_start(config, whole, (640, 640), source="gear.pto")
    with pytest.raises(rigjax.RigjaxError, match=r"gear.pto: 1 images, but the template describes 2 cameras"):
        with_start(config, rigjax.Project.new(whole.panorama, halves[:1]), (600, 600), source="gear.pto")
    with pytest.raises(rigjax.RigjaxError, match=r"lens types \[2, 3\]"):
        with_start(config, rigjax.Project.new(whole.panorama, [halves[0], halves[1].replace(projection=3)]), (600, 600))
    with pytest.raises(rigjax.RigjaxError, match="b-left.png is 640x640, but the template's lenses are of 600x600"):
        nominal_project(started, [(640, 640)] * 2, ["b-left.png", "b-right.png"])


def test_a_template_with_lenses_is_checked():
    lens = {"v": 190.0}
    with pytest.raises(rigjax.ConfigError, match="give image_size"):
        rigjax.template_from_dict({"rig": {"cameras": 1, "lenses": [lens]}})
    with pytest.raises(rigjax.ConfigError, match="2 lenses for 1 cameras"):
        rigjax.template_from_dict({"rig": {"cameras": 1, "lenses": [lens, lens], "image_size": [10, 10]}})
    with pytest.raises(rigjax.ConfigError, match="shared_lens: one lens for all cameras, but lenses"):
        rigjax.template_from_dict(
            {"rig": {"cameras": 2, "shared_lens": True, "lenses": [lens, {"v": 191.0}], "image_size": [10, 10]}}
        )


def test_a_dual_fisheye_calibrates_from_hugins_whole_frame_template(tmp_path):
    """Two lenses whose centres sit 10-14 px off their halves' centres, with a, b, c: the template's
    schedule (YPR,VYPR) holds d, e and the distortion, so the lens can only be right when it starts
    from the camera's own Hugin template. That template is written here by hand in Hugin's whole-frame
    form: for an equidistant lens the whole frame's hfov is twice the half's, and d moves by a quarter
    of the frame's width."""
    size = 720
    truth = synthetic.rig_from_orientations(
        [(0, 0, 0), (180, 0, 0)],
        width=size,
        height=size,
        projection=2,
        hfov=191.0,
        b=-0.01,
        orientation_jitter_deg=1.0,
        seed=5,
    )
    shifts = [(10.0, -12.0), (-14.0, 9.0)]
    lens = dict(a=0.004, c=-0.006)
    truth = truth.replace(images=tuple(im.replace(d=d, e=e, **lens) for im, (d, e) in zip(truth.images, shifts)))
    scene = synthetic.procedural_environment(4096, seed=2)
    frame = np.concatenate(synthetic.render_images(truth, scene, noise_std=2.0, seed=0), axis=1)
    rigjax.write_image(tmp_path / "frame.png", frame)
    whole = [
        rigjax.Image(
            width=2 * size,
            height=size,
            projection=2,
            hfov=2 * 190.0,
            b=-0.01,
            d=d + (k - 0.5) * size,
            e=e,
            yaw=180.0 * k,
            crop=(k * size, (k + 1) * size, 0, size),
            filename="frame.png",
            links=dict.fromkeys("vabc", 0) if k else {},
            **lens,
        )
        for k, (d, e) in enumerate(shifts)
    ]
    rigjax.Project.new(rigjax.PanoramaLine(2048, 1024), whole).save(tmp_path / "hugin.pto")
    out = tmp_path / "rig.pto"
    args = ["calibrate", str(tmp_path / "frame.png"), "--template", TEMPLATE, "-o", str(out), "-q"]
    assert cli.main([*args, "--start", str(tmp_path / "hugin.pto")]) == 0
    calibrated = rigjax.load_project(out)
    for image, (d, e) in zip(calibrated.images, shifts):
        assert (image.width, image.height, image.d, image.e, image.a, image.c) == (size, size, d, e, 0.004, -0.006)
        assert image.crop == (0, size, 0, size)  # the whole frame's crop, in the half's pixels
    assert calibrated.images[0].hfov == pytest.approx(191.0, abs=0.1)
    # Measured: 0.65 arcmin; from the template alone (d, e 0), written with status 0, 247 and 261.
    assert synthetic.ray_errors_arcmin(calibrated, truth).max() < 2.0
