"""What a calibration's matches leave undetermined (rigjax.calibration.checks, the bundle
adjustment's free directions): a dual fisheye whose lenses sit on one axis with their centres, seen
through points in the seam ring at unknown depths."""

import dataclasses

import jax
import numpy as np
import pytest

jax.config.update("jax_enable_x64", True)

import rigjax
from rigjax import cli, synthetic
from rigjax.calibration.checks import ChecksConfig, beyond_mounting, beyond_priors, undetermined
from rigjax.calibration.pipeline import PairMatches
from rigjax.optimiser.bundle import bundle_adjust

CENTRES = np.array([[0.0, 0.0, 0.015], [0.0, 0.0, -0.015]])  # 3 cm apart along the lenses' axis


def ring_points(n: int, seed: int, near: float = 0.5, far: float = 3.0, half_width_deg: float = 4.5) -> np.ndarray:
    """``(n, 3)`` points within ``half_width_deg`` of the plane between two back-to-back lenses
    (z = 0), ``near`` to ``far`` from the origin (log-uniform): what both 191-degree lenses see."""
    rng = np.random.default_rng(seed)
    azimuth = rng.uniform(0.0, 2.0 * np.pi, n)
    elevation = np.radians(rng.uniform(-half_width_deg, half_width_deg, n))
    directions = np.stack(
        [np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth), np.sin(elevation)], axis=1
    )
    return directions * np.exp(rng.uniform(np.log(near), np.log(far), n))[:, None]


def dual(jitter_deg: float = 0.0, noise_px: float = 0.3):
    """Two 191-degree circular fisheyes back to back (1024 px), their control points in the ring."""
    truth = synthetic.rig_from_orientations(
        [(0, 0, 0), (180, 0, 0)],
        width=1024,
        height=1024,
        projection=2,
        hfov=191.0,
        b=0.0,
        orientation_jitter_deg=jitter_deg,
        seed=3,
    )
    project, _ = synthetic.control_points_from_scene(truth, CENTRES, ring_points(400, 1), noise_px=noise_px, seed=1)
    return truth, project


@pytest.fixture(scope="module")
def free():
    """The ring's noisy matches adjusted with each hfov estimated (``VYPR``)."""
    _, noisy = dual()
    return bundle_adjust(noisy, CENTRES, "VYPR")


def test_a_lens_the_ring_points_absorb_is_reported_free(free):
    truth, exact = dual(noise_px=0.0)
    # The independent evidence: 2 degrees more hfov on both lenses, and the points' depths (with the
    # second lens's orientation) take it up exactly: the matches cannot tell the hfov.
    wider = exact.replace(images=tuple(dataclasses.replace(im, hfov=im.hfov + 2.0) for im in exact.images))
    assert bundle_adjust(wider, CENTRES, "YPR").rms < 1e-8
    # So with the hfov estimated, its deviation is unbounded ('free'), not a number of round-off.
    assert np.isinf(free.standard_deviations[0, 0])
    assert "free" in rigjax.optimiser.bundle.format_deviations(free)
    # The same lenses with every centre at the origin: no depth to absorb it, the hfov is known.
    still, _ = synthetic.control_points_from_scene(truth, np.zeros((2, 3)), ring_points(400, 1), noise_px=0.3, seed=1)
    known = bundle_adjust(still, np.zeros((2, 3)), "VYPR")
    assert np.all(known.standard_deviations[:, 0] < 0.5)
    assert abs(known.project.images[0].hfov - 191.0) < 4 * known.standard_deviations[0, 0]
    assert np.isfinite(known.orientation_sd_deg).all()


def test_a_dual_rig_with_its_lens_offset_and_known_depths_is_recovered_to_round_off():
    """The lenses 3 cm apart, exact matches of points 0.5-3 m away in the ring: with the lens held
    (the ring cannot tell it, above), the second lens's orientation and every point's depth come
    back to round-off from a start a degree off."""
    truth, _ = dual(jitter_deg=2.0)
    points = ring_points(400, 2)
    exact, index = synthetic.control_points_from_scene(truth, CENTRES, points)
    start = synthetic.perturb(exact, angle_deg=(0.5, 1.0), hfov_offset_deg=(0.0, 0.0), seed=4)
    assert abs(start.images[1].yaw - truth.images[1].yaw) >= 0.5
    result = bundle_adjust(start, CENTRES, "YPR")
    assert result.ok and result.rms < 1e-9
    for field in ("yaw", "pitch", "roll"):
        assert abs(getattr(result.project.images[1], field) - getattr(truth.images[1], field)) < 1e-9, field
    np.testing.assert_allclose(result.inverse_depths, 1.0 / np.linalg.norm(points[index], axis=1), rtol=1e-8)


def test_free_deviations_are_written_and_read_back(free, tmp_path):
    result = free
    result.project.save(tmp_path / "rig.pto")
    assert "#-rigjax sd 0 vfree" in (tmp_path / "rig.pto").read_text()
    back = rigjax.load_project(tmp_path / "rig.pto")
    np.testing.assert_allclose(  # 15 significant digits, as Hugin writes numbers
        back.deviations[np.isfinite(back.deviations)],
        result.standard_deviations[np.isfinite(result.standard_deviations)],
        rtol=1e-14,
    )
    assert np.isinf(back.deviations[0, 0])


def template_data(priors=None) -> dict:
    """The dual-fisheye template of these tests: the lenses on the axis through their centres."""
    return {
        "rig": {
            "cameras": 2,
            "projection": 2,
            "hfov": 190.0,
            "orientations": [[0, 0, 0], [180, 0, 0]],
            "centres": CENTRES.tolist(),
        },
        "ransac": {"threshold_deg": 1.0, "min_inliers": 8},
        "levy": False,
        "optimise": {"objective": "reprojection", "schedule": "YPR,VYPR", **({"priors": priors} if priors else {})},
    }


def template(priors=None, checks=None):
    return rigjax.template_from_dict(template_data(priors) | ({"checks": checks} if checks else {}))


def ring_matches():
    _, project = dual()
    cps = project.control_points
    return [PairMatches(0, 1, cps.xy_a, cps.xy_b)]


@pytest.fixture(scope="module")
def calibration():
    """rigjax.calibrate_matches of the ring's matches with the template (no prior on the lens)."""
    return rigjax.calibrate_matches(ring_matches(), [(1024, 1024)] * 2, template())


def test_calibration_names_an_undetermined_hfov_and_stands_on_a_prior(calibration):
    pairs = ring_matches()
    # Camera 0's hfov: exactly free (the anchor, its axis held on the baseline); camera 1's: barely held
    # (its fitted orientation leaves its axis a little off the baseline; a standard deviation of degrees).
    first, second = calibration.undetermined
    assert first.startswith("camera 0: hfov") and "not determined by the matches (they leave it free)" in first
    assert second.startswith("camera 1: hfov") and "standard deviation above checks.max_hfov_sd_deg 1)" in second
    # With the template's prior the hfov is the prior's, said in a note, and nothing is refused.
    held = rigjax.calibrate_matches(pairs, [(1024, 1024)] * 2, template(priors={"v": 2.0}))
    assert held.undetermined == ()
    assert len(held.notes) == 2 and "comes from its prior (optimise.priors v: 2)" in held.notes[0]
    assert held.notes[0] in held.summary()
    assert abs(held.project.images[0].hfov - 190.0) < 2.0


def test_a_lens_outside_the_plausible_range_is_named():
    _, noisy = dual()
    one_lens = noisy.replace(images=(noisy.images[0], dataclasses.replace(noisy.images[1], links={"v": 0})))
    result = bundle_adjust(one_lens, CENTRES, "VYPR", priors={"v": 2.0})
    assert undetermined(result.project, result, ChecksConfig(), 190.0, prior_v=2.0) == ()
    wide = result.project.replace(images=tuple(dataclasses.replace(im, hfov=274.6) for im in result.project.images))
    lines = undetermined(wide, result, ChecksConfig(), 190.0, prior_v=2.0)
    assert (
        lines[0].startswith("cameras 0, 1 (one lens): hfov 274.60")
        and "161.5-218.5 deg (checks.hfov_range)" in lines[0]
    )
    assert undetermined(wide, result, ChecksConfig(hfov_range=(150.0, 280.0)), 190.0, prior_v=2.0) == ()
    strict = undetermined(result.project, result, ChecksConfig(max_turn_sd_deg=1e-4), 190.0, prior_v=2.0)
    assert [line.split(":")[0] for line in strict] == ["camera 0", "camera 1"]
    assert "orientation ± " in strict[0] and "checks.max_turn_sd_deg 0.0001" in strict[0]


def test_a_lens_or_a_turn_beyond_the_rigs_tolerance_is_named():
    nominal, _ = dual()
    nominal = nominal.replace(
        images=(
            dataclasses.replace(nominal.images[0], hfov=190.0),
            dataclasses.replace(nominal.images[1], hfov=190.0, links={"v": 0}),
        )
    )

    def changed(k, **fields):
        images = list(nominal.images)
        images[k] = dataclasses.replace(images[k], **fields)
        return nominal.replace(images=tuple(images))

    # 3.5 degrees from 190 is 3.5 deviations of a 1-degree prior: beyond 3, within 4.
    lens = nominal.replace(images=tuple(dataclasses.replace(im, hfov=193.5) for im in nominal.images))
    (line,) = beyond_priors(lens, nominal, {"V": 1.0}, ChecksConfig())
    assert line.startswith("cameras 0, 1 (one lens): hfov 193.50 deg is 3.5 standard deviations of its prior")
    assert beyond_priors(lens, lens, {"V": 1.0}, ChecksConfig()) == ()
    assert beyond_priors(lens, nominal, {"V": 1.0}, ChecksConfig(max_prior_sigmas=4.0)) == ()
    # A yaw prior compares the short way round: -179 is 2 degrees from 179.
    turned, base = changed(1, yaw=-179.0), changed(1, yaw=179.0)
    assert beyond_priors(turned, base, {"Y": 1.0}, ChecksConfig(max_prior_sigmas=2.5)) == ()
    (line,) = beyond_priors(turned, base, {"Y": 1.0}, ChecksConfig(max_prior_sigmas=1.5))
    assert line.startswith("camera 1: yaw -179.00 deg is 2.0 standard deviations")
    # The layout: the rig turned as a whole is no turn; one lens turned by 10 degrees against the
    # other is 5 degrees for each, the rig's own turn removed.
    whole = nominal.replace(images=tuple(dataclasses.replace(im, yaw=im.yaw + 30.0) for im in nominal.images))
    limit = ChecksConfig(max_turn_from_nominal_deg=4.0)
    assert beyond_mounting(whole, nominal, limit) == () and beyond_mounting(lens, nominal, ChecksConfig()) == ()
    apart = changed(1, yaw=nominal.images[1].yaw + 10.0)
    lines = beyond_mounting(apart, nominal, limit)
    assert [line.split(":")[0] for line in lines] == ["camera 0", "camera 1"] and "turned 5.00 deg" in lines[1]
    assert beyond_mounting(apart, nominal, ChecksConfig(max_turn_from_nominal_deg=5.5)) == ()


@pytest.mark.parametrize(
    "checks, message",
    [
        ({"hfov_range": [200, 180]}, "hfov_range: expected"),
        ({"max_hfov_sd_deg": 0}, "max_hfov_sd_deg: expected a standard deviation"),
        ({"max_prior_sigmas": 0}, "max_prior_sigmas: expected a number of standard deviations"),
        ({"max_turn_from_nominal_deg": 200}, r"max_turn_from_nominal_deg: expected degrees in \(0, 180\]"),
        ({"max_turn": 1}, "max_turn"),
    ],
)
def test_bad_checks_are_refused_with_the_key(checks, message):
    with pytest.raises(rigjax.RigjaxError, match=message):
        template(checks=checks)


def test_command_line_refuses_to_write_an_undetermined_rig(calibration, tmp_path, monkeypatch, capsys):
    import yaml

    from rigjax.calibration import job

    # The images' matches are the ring's above (the command's matching is tested elsewhere).
    monkeypatch.setattr(job, "calibrate_frames", lambda *args, **kwargs: calibration)
    path = tmp_path / "dual.yaml"
    path.write_text(yaml.safe_dump(template_data()))
    for name in ("a.png", "b.png"):
        rigjax.write_image(tmp_path / name, np.zeros((64, 64, 3), np.uint8))
    command = ["calibrate", str(tmp_path / "a.png"), str(tmp_path / "b.png"), "--template", str(path), "-q"]
    out = tmp_path / "rig.pto"
    assert cli.main([*command, "-o", str(out)]) == 3
    error = capsys.readouterr().err.strip().splitlines()
    assert len(error) == 1 and error[0].startswith(f"rigjax calibrate: {out} not written: camera 0: hfov")
    assert "--keep-undetermined" in error[0] and not out.exists()
    assert cli.main([*command, "-o", str(out), "--keep-undetermined"]) == 3
    written = out.read_text()
    assert f"#-rigjax undetermined: {calibration.undetermined[0]}" in written
    assert rigjax.load_project(out).images[0].hfov == pytest.approx(calibration.project.images[0].hfov)


def test_command_line_says_why_a_written_rig_ends_in_status_3(calibration, tmp_path, monkeypatch, capsys):
    import yaml

    from rigjax.calibration import job

    stopped = dataclasses.replace(
        calibration.result, stages=(calibration.result.stages[-1]._replace(status="max_steps", steps=100),)
    )
    monkeypatch.setattr(
        job,
        "calibrate_frames",
        lambda *args, **kwargs: dataclasses.replace(calibration, undetermined=(), result=stopped),
    )
    path = tmp_path / "dual.yaml"
    path.write_text(yaml.safe_dump(template_data()))
    for name in ("a.png", "b.png"):
        rigjax.write_image(tmp_path / name, np.zeros((64, 64, 3), np.uint8))
    out = tmp_path / "rig.pto"
    command = ["calibrate", str(tmp_path / "a.png"), str(tmp_path / "b.png"), "--template", str(path), "-q"]
    assert cli.main([*command, "-o", str(out)]) == 3 and out.exists()
    error = capsys.readouterr().err.strip().splitlines()
    assert error == [
        "rigjax calibrate: written, but its last solve (VYPR) stopped without converging: max_steps after 100 "
        "steps (optimise.solver.max_steps in the template)"
    ]


def _job_inputs(tmp_path):
    import yaml

    path = tmp_path / "dual.yaml"
    path.write_text(yaml.safe_dump(template_data()))
    for name in ("a.png", "b.png"):
        rigjax.write_image(tmp_path / name, np.zeros((64, 64, 3), np.uint8))
    return path, (str(tmp_path / "a.png"), str(tmp_path / "b.png"))


def test_calibrate_job_refuses_with_the_status_and_the_reason(calibration, tmp_path, monkeypatch):
    from rigjax.calibration import job

    monkeypatch.setattr(job, "calibrate_frames", lambda *args, **kwargs: calibration)
    template_path, images = _job_inputs(tmp_path)
    out = tmp_path / "rig.pto"
    refused = job.calibrate_job(job.CalibrateJob(template_path, out, images=images))
    reason = "; ".join(calibration.undetermined)
    assert refused.status == 3 and refused.refusal == reason and reason.startswith("camera 0: hfov")
    assert refused.written == () and not out.exists() and refused.calibration is calibration
    assert refused.lines == (
        job.Line(calibration.summary()),
        job.Line(f"rigjax calibrate: {out} not written: {reason} (--keep-undetermined writes it)", error=True),
    )
    kept = job.calibrate_job(job.CalibrateJob(template_path, out, images=images, keep_undetermined=True))
    assert kept.status == 3 and kept.refusal is None and kept.written == (str(out),)
    assert [line.text for line in kept.lines if line.error] == [
        f"warning: written with parameters the matches do not determine: {reason}"
    ]
    assert f"#-rigjax undetermined: {calibration.undetermined[0]}" in out.read_text()


def test_calibrate_job_returns_what_the_command_prints_and_writes(calibration, tmp_path, monkeypatch, capsys):
    from rigjax.calibration import job

    settled = dataclasses.replace(calibration, undetermined=())
    monkeypatch.setattr(job, "calibrate_frames", lambda *args, **kwargs: settled)
    template_path, images = _job_inputs(tmp_path)
    out = tmp_path / "rig.pto"
    done = job.calibrate_job(job.CalibrateJob(template_path, out, images=images))
    assert done.status == 0 and done.refusal is None and done.written == (str(out),)
    assert rigjax.load_project(out).images[1].yaw == pytest.approx(settled.project.images[1].yaw)
    command = ["calibrate", *images, "--template", str(template_path), "-o", str(out), "-q"]
    assert cli.main(command) == done.status
    printed = capsys.readouterr()
    assert printed.out == "".join(f"{line.text}\n" for line in done.lines if not line.error) and printed.err == ""


def test_calibrate_job_emits_the_summary_before_it_writes(calibration, tmp_path, monkeypatch):
    # A render that fails after the project is written: the user has still seen the summary and
    # the project's line, in order, as the command prints them.
    from rigjax.calibration import job

    settled = dataclasses.replace(calibration, undetermined=())
    monkeypatch.setattr(job, "calibrate_frames", lambda *args, **kwargs: settled)

    def broken_render(*args, **kwargs):
        raise rigjax.ImageError("the disk is full")

    monkeypatch.setattr(job, "render", broken_render)
    template_path, images = _job_inputs(tmp_path)
    out, seen = tmp_path / "rig.pto", []
    with pytest.raises(rigjax.ImageError, match="the disk is full"):
        job.calibrate_job(
            job.CalibrateJob(template_path, out, images=images, render=str(tmp_path / "pano.jpg")), emit=seen.append
        )
    assert seen == [job.Line(settled.summary()), job.Line(f"wrote {out}")] and out.exists()


@pytest.mark.parametrize(
    "fields, message",
    [
        ({"every": 2}, "--every reads frames of --video files"),
        ({"videos": ("a.avi",)}, "give images or --video files, not both"),
        ({"images": ()}, "give one image per camera, or --video files"),
    ],
)
def test_calibrate_job_names_inputs_that_do_not_go_together(tmp_path, fields, message):
    from rigjax.calibration import job

    template_path, images = _job_inputs(tmp_path)
    bad = dataclasses.replace(job.CalibrateJob(template_path, tmp_path / "rig.pto", images=images), **fields)
    with pytest.raises(job.JobError, match=message):
        job.calibrate_job(bad)


def test_video_frames_are_named_by_their_time_and_offset():
    from rigjax.calibration.job import video_frame_names

    assert video_frame_names(["in/front.mp4", "back.mp4"], 1.5, 10, 2) == [
        "front_1.5s.png",
        "back_1.5s.png",
        "front_1.5s+10.png",
        "back_1.5s+10.png",
    ]


def test_a_lens_letter_its_prior_fixes_is_noted_in_the_projects_units():
    """held_by_prior: the bundle adjustment's deviations of a, b, c are in its internal unit (0.01 of
    the project's): a b known to 0.45 (45 internal) is its prior's 0.5 at 90 %, noted; 0.30 is not."""
    from types import SimpleNamespace

    from rigjax.calibration.checks import held_by_prior

    project = rigjax.Project.new(
        rigjax.PanoramaLine(360, 180), [rigjax.Image(width=64, height=64, projection=2, b=0.02) for _ in range(2)]
    )
    deviations = np.full((2, 9), np.nan)
    deviations[:, 2] = [45.0, 30.0]
    (line,) = held_by_prior(project, SimpleNamespace(standard_deviations=deviations), {"B": 0.5}, "motion.priors")
    assert line == "note: camera 0: b 0.0200 ± 0.4500 comes from its prior (motion.priors b: 0.5), not from the matches"
