"""``rigjax calibrate`` end to end on synthetic images of a 6-camera ring of 1440x1080 full-frame
fisheyes (hfov 123, K2 -0.01) looking at a procedural environment at infinity: the truth is exact."""

import dataclasses
import subprocess
import sys
from pathlib import Path

import jax
import numpy as np
import pytest

jax.config.update("jax_enable_x64", True)

import rigjax
from rigjax import cli, synthetic

TEMPLATE = "configs/rig/ring6.yaml"


@pytest.fixture(scope="module")
def ring():
    truth = synthetic.ring_rig(orientation_jitter_deg=2.0, seed=1)
    images = synthetic.render_images(truth, synthetic.procedural_environment(4096, seed=0), noise_std=2.0, seed=0)
    config = rigjax.load_template(TEMPLATE)
    # Lighter search than the template's, for test time; the benchmark runs the template's.
    config = dataclasses.replace(
        config,
        levy=rigjax.LevyConfig(candidates=128, generations=2, starts=4),
        features=dataclasses.replace(config.features, max_points_per_pair=200),
    )
    matches = rigjax.match_images(images, config)
    return truth, images, config, matches


def _with_orientations(config, orientations):
    return dataclasses.replace(
        config, rig=dataclasses.replace(config.rig, orientations=tuple(map(tuple, orientations)))
    )


def _inject_wrong_matches(matches, fraction, seed):
    """``fraction`` more matches per pair, each joining random pixels: wrong matches."""
    rng = np.random.default_rng(seed)
    out = []
    for pair in matches:
        n = int(round(fraction * len(pair.xy_a)))
        wrong_a = rng.uniform([0, 0], [1439, 1079], (n, 2))
        wrong_b = rng.uniform([0, 0], [1439, 1079], (n, 2))
        out.append(pair._replace(xy_a=np.concatenate([pair.xy_a, wrong_a]), xy_b=np.concatenate([pair.xy_b, wrong_b])))
    return out


def _check(calibration, truth, limit_arcmin):
    errors = synthetic.ray_errors_arcmin(calibration.project, truth)
    assert errors.max() < limit_arcmin, errors
    hfov = np.array([im.hfov for im in calibration.project.images])
    np.testing.assert_allclose(hfov, 123.0, atol=0.05)
    # At the statistical optimum: no better explained by the truth on the same points.
    kept = calibration.pruned.kept.astype(float)
    floor = rigjax.evaluate(truth.replace(control_points=calibration.start.control_points), weights=kept).rms
    assert calibration.result.rms <= floor * 1.001
    return errors


def test_three_degrees_off_with_nominal_fov_and_thirty_percent_wrong_matches(ring):
    truth, _, config, matches = ring
    start = [[im.yaw + 3.0 * (-1) ** k, im.pitch - 3.0, im.roll + 3.0] for k, im in enumerate(truth.images)]
    start[0] = [truth.images[0].yaw, truth.images[0].pitch, truth.images[0].roll]
    noisy = _inject_wrong_matches(matches, 0.3, seed=4)
    config = dataclasses.replace(_with_orientations(config, start), levy=None)  # plain LM suffices 3 degrees off
    calibration = rigjax.calibrate_matches(noisy, [(1440, 1080)] * 6, config)
    injected = sum(len(p.xy_a) for p in noisy) - sum(len(p.xy_a) for p in matches)
    assert sum(p.matches for p in calibration.pairs) == sum(len(p.xy_a) for p in noisy)
    assert sum(p.matches - p.inliers for p in calibration.pairs) >= injected * 0.99  # RANSAC removed them
    _check(calibration, truth, 1.0)


def test_starts_up_to_45_degrees_off_in_yaw(ring):
    truth, _, config, matches = ring
    offsets = [0.0, 45.0, -40.0, 35.0, -45.0, 30.0]
    start = [[im.yaw + d, im.pitch, im.roll] for im, d in zip(truth.images, offsets)]
    calibration = rigjax.calibrate_matches(matches, [(1440, 1080)] * 6, _with_orientations(config, start))
    _check(calibration, truth, 1.0)


def test_closed_form_initial_values_without_orientations(ring):
    truth, _, config, matches = ring
    config = dataclasses.replace(_with_orientations(config, [[0, 0, 0]] * 6), levy=None)
    config = dataclasses.replace(config, rig=dataclasses.replace(config.rig, orientations=None))
    calibration = rigjax.calibrate_matches(matches, [(1440, 1080)] * 6, config)
    # Before LM: the spanning tree's orientations (from the nominal lens) err by the lens; the
    # rays are compared through the true lens, so that only the orientations differ.
    lens = [im.replace(hfov=t.hfov, b=t.b) for im, t in zip(calibration.start.images, truth.images)]
    start_errors = synthetic.ray_errors_arcmin(calibration.start.replace(images=tuple(lens)), truth)
    assert start_errors.max() < 6 * 60  # measured 4.2 degrees: each link of the chain errs by ~1 degree
    _check(calibration, truth, 1.0)


def test_bad_input_names_the_images_and_the_pair(ring, tmp_path):
    truth, images, config, matches = ring
    with pytest.raises(rigjax.CalibrationError, match=r"takes 6 image\(s\) per frame \(6 cameras\), but 5 images"):
        rigjax.calibrate(images[:5], config)
    shared = dataclasses.replace(config, rig=dataclasses.replace(config.rig, shared_lens=True))
    small = [images[0]] + [images[1][:1000]] + images[2:]
    with pytest.raises(rigjax.CalibrationError, match=r"b.png is 1440x1000 but a.png is 1440x1080: .*shared_lens"):
        rigjax.match_images(small, shared, names=["a.png", "b.png", "c", "d", "e", "f"])
    # Cameras 0 and 3 face away from each other: a template that says they overlap is wrong.
    facing = dataclasses.replace(config, rig=dataclasses.replace(config.rig, overlaps=((0, 1), (0, 3))))
    pairs = [p for p in matches if (p.a, p.b) in ((0, 1), (0, 3))]
    with pytest.raises(rigjax.CalibrationError, match=r"cameras 0 \(cam0.png\) and 3 \(cam3.png\) should overlap"):
        rigjax.calibrate_matches(pairs, [(1440, 1080)] * 6, facing, names=[f"cam{k}.png" for k in range(6)])
    not_an_image = tmp_path / "cam0.png"
    not_an_image.write_text("not an image")
    with pytest.raises(rigjax.ImageError, match=r"cam0.png: cannot read the image"):
        rigjax.read_image(not_an_image)
    out = subprocess.run(
        [
            sys.executable,
            "-m",
            "rigjax.cli",
            "calibrate",
            str(not_an_image),
            "--template",
            TEMPLATE,
            "-o",
            str(tmp_path / "rig.pto"),
        ],
        capture_output=True,
        text=True,
    )
    assert out.returncode == 2 and "cam0.png: cannot read the image" in out.stderr


def test_demo_calibrates_the_synthetic_rig_from_its_images(tmp_path, capsys):
    # The ring6 template without the Lévy search (the tests above cover it) and with their 200 points per
    # pair: the demo's rig is the fixture's, so this test reuses their compiled solves (one file, one process).
    template = Path("configs/rig/ring6.yaml").read_text().replace("\nlevy: {", "\n# levy: {") + "levy: false\n"
    template = template.replace("max_points_per_pair: 400", "max_points_per_pair: 200")
    assert "max_points_per_pair: 200" in template
    (tmp_path / "ring6.yaml").write_text(template)
    assert cli.main(["demo", "--out", str(tmp_path), "--template", str(tmp_path / "ring6.yaml")]) == 0
    out = capsys.readouterr().out
    truth = rigjax.load_project(tmp_path / "truth.pto")
    calibrated = rigjax.load_project(tmp_path / "rig.pto")
    assert len(calibrated.images) == 6 and len(calibrated.control_points) > 1000
    # The demo's own table, checked against the truth independently.
    assert rigjax.synthetic.ray_errors_arcmin(calibrated, truth).max() < 1.0
    rows = [line.split() for line in out.splitlines() if line[:3].strip().isdigit() and len(line.split()) == 4]
    assert len(rows) == 6 and max(float(r[-1]) for r in rows) < 1.0
    psnr = float(out.split("PSNR ")[1].split()[0])
    assert psnr > 30.0
