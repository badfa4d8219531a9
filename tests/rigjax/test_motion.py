"""Lenses from the camera's own motion (rigjax.calibration.motion): a turning dual fisheye whose
lenses have shifted centres and Hugin's a, b, c, made here through rigjax's camera model, its
truth known exactly."""

import dataclasses
from pathlib import Path

import jax
import numpy as np
import pytest

jax.config.update("jax_enable_x64", True)

import rigjax
from rigjax import synthetic
from rigjax.calibration import pipeline
from rigjax.calibration.circle import ImageCircle
from rigjax.calibration.motion import (
    MotionConfig,
    across_frames,
    across_tracks,
    circle_priors,
    frames_centres,
    frames_project,
    ransac_pairs,
    rigid_frames,
    solve_motion,
    split_rig,
    start_from_pairs,
    turn_between_deg,
)
from rigjax.calibration.pipeline import calibrate_frames, frames_of
from rigjax.calibration.template import PhotometryConfig
from rigjax.camera.photometry import vignetting
from rigjax.camera.rotation import world_from_cam
from rigjax.config import read_yaml
from rigjax.optimiser.bundle import bundle_adjust
from rigjax.optimiser.config import OptimiseConfig, Priors
from rigjax.pto.records import ControlPoints

# Two lenses like a real consumer camera's (Hugin calibrations of one put a, b, c near -0.28, 0.52,
# -0.14 and the optical centres 20-25 px below the image centres at 1440 px), mounted about back to back.
LENSES = (
    dict(hfov=193.0, a=-0.28, b=0.52, c=-0.14, d=12.0, e=25.5),
    dict(hfov=191.5, a=-0.25, b=0.47, c=-0.12, d=-8.0, e=19.9),
)
MOUNTING = ((0.0, 0.0, 0.0), (179.3, -0.4, 0.3))


def rig(size, lenses=LENSES, mounting=MOUNTING, names=("f0-0.png", "f0-1.png")):
    scale = size / 1440.0
    images = [
        rigjax.Image(
            width=size,
            height=size,
            projection=2,
            **{**lens, "d": lens.get("d", 0.0) * scale, "e": lens.get("e", 0.0) * scale},
            yaw=y,
            pitch=p,
            roll=r,
            filename=names[k],
        )
        for k, (lens, (y, p, r)) in enumerate(zip(lenses, mounting))
    ]
    return rigjax.Project.new(rigjax.PanoramaLine(4096, 2048), images)


def turning(frames, step_deg=8.0, seed=1):
    """The camera's orientation in each frame: ``step_deg`` more yaw a frame, a few degrees of
    pitch and roll (a hand-held turn)."""
    rng = np.random.default_rng(seed)
    return np.stack(
        [np.asarray(world_from_cam(step_deg * f, rng.uniform(-3, 3), rng.uniform(-3, 3))) for f in range(frames)]
    )


def names_of(frames):
    return [[f"f{f}-{k}.png" for k in range(2)] for f in range(frames)]


def test_a_rig_split_from_its_frames_is_the_rig_and_its_turns():
    truth, turns = rig(720), turning(4)
    frames = frames_project(truth, turns, names_of(4))
    assert frames.images[5].links == {x: 1 for x in "vabcde"} and frames.images[1].links == {}
    got, got_turns, spread = split_rig(frames, 2)
    seen = frames.images[:2]  # the rig as frame 0 sees it
    for a, b in zip(got.images, seen):
        for x in ("hfov", "a", "b", "c", "d", "e", "yaw", "pitch", "roll"):
            assert getattr(a, x) == pytest.approx(getattr(b, x), abs=1e-9)
    world = np.asarray(world_from_cam(*(got_turns[:, k] for k in range(3))))
    np.testing.assert_allclose(world, turns @ turns[0].T, atol=1e-12)
    assert truth.images[1].yaw != pytest.approx(seen[1].yaw)  # frame 0 is turned
    np.testing.assert_allclose(spread, 0.0, atol=1e-9)
    # The turn between two frames, for turns about one axis: the difference of their angles.
    np.testing.assert_allclose(
        turn_between_deg(np.array([[0.0, 0.0, 0.0], [8.0, 0.0, 0.0], [21.0, 0.0, 0.0]])),
        [[0, 8, 21], [8, 0, 13], [21, 13, 0]],
        atol=1e-9,
    )


def test_lenses_with_shifts_and_abc_are_recovered_to_round_off_from_exact_matches():
    """Exact matches of every pair of a turning camera's images (each lens with itself across frames,
    and the ring between the lenses): RANSAC on the nominal lens, placement in closed form and the
    bundle adjustment (no priors) give both lenses' hfov, a, b, c, d, e and the mounting to round-off."""
    frames, truth, turns = 5, rig(1440), turning(5)
    names = names_of(frames)
    exact = synthetic.control_points_from_truth(frames_project(truth, turns, names), 400, seed=2).control_points
    pairs = []
    for a in range(2 * frames):
        for b in range(a + 1, 2 * frames):
            m = (exact.image_a == a) & (exact.image_b == b)
            if m.any():
                pairs.append((a, b, exact.xy_a[m], exact.xy_b[m]))
    assert any(a % 2 == b % 2 for a, b, *_ in pairs) and any(a // 2 == b // 2 for a, b, *_ in pairs)
    nominal = rig(1440, lenses=(dict(hfov=190.0), dict(hfov=190.0)), mounting=((0, 0, 0), (180, 0, 0)))
    fits = ransac_pairs(pairs, nominal, threshold_deg=5.0, iterations=500, seed=0)
    start = start_from_pairs(nominal, frames, fits, names, min_inliers=10, max_points_per_pair=100, seed=0)
    fit = solve_motion(start, 2, MotionConfig(priors=Priors()), OptimiseConfig(prune=None))
    assert fit.result.ok and fit.result.rms < 1e-9
    for got, want in zip(fit.rig.images, truth.images):
        for x in ("hfov", "a", "b", "c", "d", "e", "yaw", "pitch", "roll"):
            assert getattr(got, x) == pytest.approx(getattr(want, x), abs=1e-8), x
    assert max(e.max() for e in synthetic.ray_angles_deg(fit.rig, truth)) < 1e-9
    world = np.asarray(world_from_cam(*(fit.turns[:, k] for k in range(3))))
    np.testing.assert_allclose(world, turns[0].T[None] @ turns, atol=1e-10)  # frame 0's turn is the frame


@pytest.mark.parametrize("noise_px", [0.0, 0.3])
def test_a_near_object_across_the_seam_is_seen_from_each_lenss_own_centre(noise_px):
    """The ring of each frame sees scene points 0.6-4 m away from the lenses' centres (2.5 cm apart
    along their axis, turning with the camera) and far content; each lens matched with itself across
    frames sees far content (at infinity). The ring's near points at their own depths, its far ones
    and the matches across frames at infinity, give the lenses to round-off from exact matches; with
    noise, the near points are told from the far by their parallax. The same matches solved with the
    lenses at one point (rotation-only) bend the lenses by a tenth of a degree or more."""
    frames, truth = 5, rig(1440)
    turns = turning(5)
    turns = turns[0].T[None] @ turns  # the rig's frame is frame 0's
    names, centres = names_of(frames), np.array([[0.0, 0.0, 0.0125], [0.0, 0.0, -0.0125]])
    true_frames = frames_project(truth, turns, names)
    world = frames_centres(true_frames, 2, centres)  # each lens's centre carried by its frame's turn
    np.testing.assert_allclose(world.reshape(frames, 2, 3), np.einsum("fij,lj->fli", turns, centres), atol=1e-15)
    scene = synthetic.scene_points(900, near=0.6, far=4.0, seed=4)
    near, _ = synthetic.control_points_from_scene(true_frames, world, scene, noise_px=noise_px, seed=5)
    far = synthetic.control_points_from_truth(true_frames, 360, noise_px=noise_px, seed=2)
    pairs, flags = [], []  # each pair's matches, and which of them are near
    for a in range(2 * frames):
        for b in range(a + 1, 2 * frames):
            ends = [
                (p.control_points, (p.control_points.image_a == a) & (p.control_points.image_b == b))
                for p in (near, far)
            ]
            if a // 2 != b // 2:  # across frames: far content only, 50 matches at most
                ends = [
                    (ends[0][0], np.zeros_like(ends[0][1])),
                    (ends[1][0], ends[1][1] & (np.cumsum(ends[1][1]) <= 50)),
                ]
            if any(m.any() for _, m in ends):
                pairs.append(
                    (
                        a,
                        b,
                        *(np.concatenate([cps.xy_a[m] if k == 0 else cps.xy_b[m] for cps, m in ends]) for k in (0, 1)),
                    )
                )
                flags.append(np.concatenate([np.full(int(m.sum()), j == 0) for j, (_, m) in enumerate(ends)]))
    nominal = rig(1440, lenses=(dict(hfov=190.0), dict(hfov=190.0)), mounting=((0, 0, 0), (180, 0, 0)))
    fits = ransac_pairs(pairs, nominal, threshold_deg=5.0, iterations=500, seed=0)
    start = start_from_pairs(nominal, frames, fits, names, min_inliers=10, max_points_per_pair=10**6, seed=0)
    used = [fit.b_from_a is not None and fit.inliers.sum() >= 10 for fit in fits]
    is_near = np.concatenate([flag[fit.inliers] for fit, flag, u in zip(fits, flags, used) if u])
    ring = ~across_frames(start, 2)
    assert (ring & is_near).sum() > 200 and (ring & ~is_near).sum() > 200 and (~ring).sum() > 1000
    settings = OptimiseConfig(prune=None)
    fit = solve_motion(start, 2, MotionConfig(priors=Priors()), settings, centres=centres, spread=False)
    # The start's turns place the centres, a few degrees off the truth: solved again from the first
    # fit's turns, as the calibration's passes do.
    fit = solve_motion(fit.result.project, 2, MotionConfig(priors=Priors()), settings, centres=centres)
    rays = synthetic.ray_angles_deg(fit.rig, truth)
    # frame 1's lens 1 follows its rig: its orientation's deviation carries those it follows
    sd = fit.result.orientation_sd_deg
    assert np.isfinite(sd).all() and 0.3 < sd[3] / sd[1] < 3.0
    finite = fit.result.inverse_depths > 0.0
    assert not finite[~ring].any()  # across frames: at infinity
    if noise_px == 0.0:
        assert fit.result.ok and fit.result.rms < 1e-4  # each solve from better-placed centres: closer still
        assert max(e.max() for e in rays) < 1e-4
        assert finite[ring & is_near].all() and fit.result.inverse_depths[ring & is_near].min() > 0.2
    else:
        assert finite[ring & is_near].mean() > 0.9 and finite[ring & ~is_near].mean() < 0.05
        assert max(np.percentile(e, 95) for e in rays) < 0.03
    if noise_px == 0.0:
        one_point = solve_motion(start, 2, MotionConfig(priors=Priors()), settings, spread=False)
        assert max(np.percentile(e, 95) for e in synthetic.ray_angles_deg(one_point.rig, truth)) > 0.1


@pytest.fixture(scope="module")
def turning_clip():
    """Three side-by-side frames (2 x 480 px) of the camera turning under a procedural sky at infinity."""
    frames, size = 3, 480
    truth, turns = rig(size), turning(frames, step_deg=10.0)
    environment = synthetic.procedural_environment(2048, seed=3)
    views = synthetic.render_images(frames_project(truth, turns, names_of(frames)), environment, noise_std=1.0)
    return truth, turns, [np.concatenate(views[2 * f : 2 * f + 2], axis=1) for f in range(frames)]


def dual_template(**motion):
    data = read_yaml("configs/rig/dual_fisheye.yaml")
    data.update(motion=motion, photometry={"fit": False})
    return rigjax.template_from_dict(data, "dual_fisheye.yaml + motion")


def test_a_turning_camera_calibrates_its_lenses_from_its_frames(turning_clip, monkeypatch):
    truth, turns, clip = turning_clip
    solved = []  # the settings each bundle adjustment of the frames was given
    monkeypatch.setattr(pipeline, "solve_motion", lambda *a, **k: solved.append(a[2]) or solve_motion(*a, **k))
    config = dataclasses.replace(dual_template(), photometry=PhotometryConfig(fit=True))
    # The ring tracked once more through the calibrated lenses, not the template's twice (a bundle
    # adjustment of every frame fewer): the rays are within the bound below after one.
    config = dataclasses.replace(config, features=dataclasses.replace(config.features, retrack=1))
    names = [f"frame{f}.jpg" for f in range(len(clip))]
    calibration = calibrate_frames(frames_of(clip, config, names), config)
    assert calibration.undetermined == ()
    # Photometry across the frames: each lens's vignetting told by the turn (one frame's ring holds it,
    # tests/rigjax/test_exposure.py), here none drawn, every image's exposure 0.
    exposure = calibration.exposure
    assert len(exposure.project.images) == 2 * len(clip) and exposure.held == ()
    assert np.abs([im.exposure_value for im in exposure.project.images]).max() < 0.05
    for image in calibration.project.images:
        y, x = np.mgrid[: image.height : 8, : image.width : 8].astype(float)
        inside = np.hypot(x - image.width / 2, y - image.height / 2) < 0.45 * image.width
        assert np.abs(vignetting(image, np.stack([x, y], -1))[inside] - 1.0).max() < 0.02
    errors = synthetic.ray_angles_deg(calibration.project, truth)
    # A pixel is 0.40 deg at 480 px across 193 deg; the rays within about a fifth of one (lens 0
    # measured at 0.079-0.081 deg by runs of the same code in different processes, lens 1 at 0.03).
    assert all(np.percentile(e, 95) < 0.09 for e in errors), [np.percentile(e, 95) for e in errors]
    for got, want in zip(calibration.project.images, truth.images):
        assert abs(got.d - want.d) < 0.5 and abs(got.e - want.e) < 0.5  # the hfov trades with a, b, c: rays above
    world = np.asarray(world_from_cam(*(calibration.turns[:, k] for k in range(3))))
    relative = turns[0].T[None] @ turns  # each frame's turn from the first
    assert np.degrees(np.abs(world - relative).max()) < 0.05
    assert calibration.project.images[0].filename == "frame0-left.png" and "image circle" in calibration.notes[0]
    # Both circles found: each lens's centre held about its circle's, the 1 px default and the circle's
    # own few hundredths of a pixel together (the template's 30 px otherwise).
    (note,) = [n for n in calibration.notes if n.startswith("d, e held about the image circles' centres, sd 1.0")]
    assert solved and all(m.priors.d == m.priors.e and 1.0 < m.priors.d < 1.01 for m in solved), note
    # The rig keeps the template's lens centres, for a stitch through depth.
    np.testing.assert_array_equal(calibration.project.centres, config.rig.centres)
    summary = calibration.summary()
    assert "camera's turn per frame" in summary and " d " in summary.splitlines()[-3]


def test_frames_that_did_not_turn_are_refused_in_one_line(turning_clip, tmp_path, capsys):
    """``rigjax calibrate --motion`` (the template has no motion section: its defaults) on the same
    frame twice: the lenses cannot be told; status 3, nothing written, one line that says why."""
    from rigjax.cli import main
    from rigjax.rendering.images import write_image

    _, _, clip = turning_clip
    paths = [str(tmp_path / name) for name in ("a.png", "b.png")]
    for path in paths:
        write_image(path, clip[0])
    template = tmp_path / "dual.yaml"
    text = Path("configs/rig/dual_fisheye.yaml").read_text()  # one tracking pass: the frames are the same
    template.write_text(text.replace("retrack: 2", "retrack: 0"))
    out = tmp_path / "rig.pto"
    status = main(["calibrate", *paths, "--motion", "--template", str(template), "-o", str(out), "-q"])
    assert status == 3 and not out.exists()
    printed = capsys.readouterr()
    (line,) = [x for x in printed.err.splitlines() if x.startswith("rigjax calibrate")]
    assert "the camera turned at most 0.00 deg between two frames (motion.min_turn_deg 5)" in line
    # Frames that did not turn show each direction at one radius: the photometry is frame 0's ring's alone.
    assert (
        "(frame 0's overlaps" not in printed.out and "b-left.png" not in printed.out.split("exposure and vignetting")[1]
    )


def test_the_centres_are_held_to_the_circles_only_where_every_circle_was_found():
    def circle(centre_sd):
        return ImageCircle(np.array([700.0, 719.5]), 705.0, 0.01, centre_sd, 500, 0.25)

    motion = MotionConfig()  # circle_centre_px 1, the template's d, e priors 30 px
    solved, note = circle_priors(motion, [circle(0.02), circle(0.75)])
    assert solved.priors.d == solved.priors.e == pytest.approx(1.25)  # sqrt(1 + 0.75^2): the less certain
    assert solved.priors.v == motion.priors.v and solved.max_spread_deg == motion.max_spread_deg
    assert note == "d, e held about the image circles' centres, sd 1.25 px (motion.circle_centre_px 1)"
    # A lens whose circle was not found, no circle searched, or the hold switched off: the priors as given.
    solved, note = circle_priors(motion, [circle(0.02), None])
    assert (
        solved is motion and note == "d, e not held to the image circles: lens 1's was not found (motion.priors d, e)"
    )
    assert circle_priors(motion, []) == (motion, None)
    off = MotionConfig(circle_centre_px=None)
    assert circle_priors(off, [circle(0.02), circle(0.02)]) == (off, None)


@pytest.mark.parametrize(
    "motion, message",
    [
        ({"schedule": "YPR,VYPRX"}, "held: X does not apply"),
        ({"priors": {"x": 0.01}}, "x (centres) does not apply"),
        ({"min_turn_deg": 0}, "motion.min_turn_deg"),
        ({"max_spread_deg": -1}, "motion.max_spread_deg"),
        ({"circle_centre_px": 0}, "motion.circle_centre_px: expected a standard deviation in px (> 0) or null, got 0"),
        ({"circle_centre_px": -1.5}, "motion.circle_centre_px: expected a standard deviation in px (> 0) or null"),
        ({"tracks": "yes"}, "motion.tracks: expected true or false, got 'yes'"),
        ({"frames": 3}, "unknown key 'frames'"),
    ],
)
def test_a_bad_motion_section_is_named(motion, message):
    with pytest.raises(rigjax.RigjaxError, match=message.replace("(", r"\(").replace(")", r"\)")):
        dual_template(**motion)


def test_a_feature_followed_through_frames_is_one_point_with_one_depth():
    """A camera whose two lenses sit 1.25 cm off its middle turns through three frames, each lens
    matched with itself across frames on content 0.6-4 m away, whose parallax moves the matches by
    pixels (at infinity the lenses bend: benchmarks/motion_depth_policies.py). Each feature one track
    with a depth of its own, started 0.5 degree of hfov and 2 px of centre off, the lenses come back
    to round-off, and every control point of a track reports its one depth."""
    truth, frames = rig(1440), 3
    turns = turning(frames)
    turns = turns[0].T[None] @ turns
    true_frames = frames_project(truth, turns, names_of(frames))
    world = frames_centres(true_frames, 2, np.array([[0.0, 0.0, 0.0125], [0.0, 0.0, -0.0125]]))
    scene_points = synthetic.scene_points(120, near=0.6, far=4.0, seed=4)
    project, index = synthetic.control_points_from_scene(true_frames, world, scene_points)
    cps = project.control_points
    across = across_frames(project, 2)
    same_lens = cps.image_a % 2 == cps.image_b % 2
    keep = (across & same_lens) | ~across  # each lens with itself across frames, and the rings
    project = project.replace(
        control_points=ControlPoints(
            *(np.asarray(x)[keep] for x in (cps.image_a, cps.image_b, cps.xy_a, cps.xy_b, cps.kind))
        )
    )
    index, across = index[keep], across[keep]
    lens = np.asarray(project.control_points.image_a) % 2
    tracks = np.where(across, 2 * index + lens, -1)  # one track per scene point and lens
    assert np.bincount(tracks[tracks >= 0]).max() == 3  # features seen in all three frames
    start = project.replace(
        images=tuple(image.replace(hfov=image.hfov + 0.5, d=image.d + 2.0, e=image.e - 2.0) for image in project.images)
    )
    settings = dict(centres=world, schedule="YPR,VDEYPR,VABCDEYPR", hold_anchor=True, rigid=rigid_frames(frames, 2))
    # each match across frames where its second image would see the point at infinity: pixels off
    cameras, cps = true_frames.cameras(), project.control_points
    far, _ = rigjax.ray_to_img(cameras.take(cps.image_b[across]), scene_points[index[across]])
    assert np.median(np.hypot(*(np.asarray(far) - cps.xy_b[across]).T)) > 0.5
    tracked = bundle_adjust(start, tracks=tracks, **settings)
    rays = max(np.percentile(e, 95) for e in synthetic.ray_angles_deg(tracked.project, true_frames))
    assert rays < 1e-6 and tracked.rms < 1e-6, (rays, tracked.rms)
    depth = tracked.inverse_depths
    for t in np.unique(tracks[tracks >= 0])[:20]:
        np.testing.assert_array_equal(depth[tracks == t], depth[tracks == t][0])
    np.testing.assert_allclose(depth[across], 1.0 / np.linalg.norm(scene_points[index[across]], axis=1), rtol=1e-6)


def test_matches_across_frames_are_chained_by_the_features_they_share():
    """Three frames of two lenses (image 2 f + l): lens 0's feature seen in every frame is one track
    of its three matches; a frame's ring, a match that shares no feature, and a chain that reaches
    one image at two pixels (a wrong match joined two features) are no track."""
    a = np.array([0, 0, 2, 0, 0, 0, 2, 0])
    b = np.array([2, 4, 4, 1, 2, 2, 4, 4])
    xy_a = np.array([[1, 1], [1, 1], [2, 2], [0, 0], [5, 5], [7, 7], [8, 8], [7, 7.0]])
    xy_b = np.array([[2, 2], [3, 3], [3, 3], [0, 0], [6, 6], [8, 8], [9, 9], [10, 10.0]])
    frames = frames_project(rig(480), turning(3), names_of(3))
    frames = frames.replace(control_points=ControlPoints(a, b, xy_a, xy_b, np.zeros(8)))
    np.testing.assert_array_equal(across_tracks(frames, 2), [0, 0, 0, -1, -1, -1, -1, -1])
