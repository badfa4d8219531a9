"""A circular fisheye's image circle and the lens it implies (rigjax.calibration.circle): images
drawn here through rigjax's camera model with the circle's edge at a stated field angle."""

import dataclasses
import math

import cv2
import jax
import numpy as np
import pytest

jax.config.update("jax_enable_x64", True)

import rigjax
from rigjax import synthetic
from rigjax.calibration.circle import find_image_circle, lens_from_circle

SIZE = 720


def fisheye_frames(image, circle_deg, frames=2):
    """``frames`` images of ``image``'s lens (turned by 40 degrees a frame) of a procedural scene,
    black beyond ``circle_deg / 2`` off axis: each pixel's ray by rigjax's model, its colour the
    scene's in that direction."""
    scene = synthetic.procedural_environment(1024, seed=0).astype(float)
    camera = rigjax.Project.new(rigjax.PanoramaLine(width=360, height=180), [image]).cameras().take(0)
    y, x = np.mgrid[: image.height, : image.width].astype(float)
    ray, ok = rigjax.img_to_ray(camera, np.stack([x, y], axis=-1))
    ray, ok = np.asarray(ray), np.asarray(ok)
    inside = ok & (np.degrees(np.arccos(np.clip(ray[..., 2], -1, 1))) <= circle_deg / 2)
    out = []
    for f in range(frames):
        lon = np.arctan2(ray[..., 0], ray[..., 2]) + np.radians(40.0 * f)
        lat = np.arcsin(np.clip(ray[..., 1], -1, 1))
        u = ((lon / (2 * np.pi) + 0.5) % 1.0) * (scene.shape[1] - 1)
        v = (lat / np.pi + 0.5) * (scene.shape[0] - 1)
        colour = scene[v.round().astype(int), u.round().astype(int)]
        out.append(np.where(inside[..., None], colour, 0.0).astype(np.uint8))
    return out


@pytest.mark.parametrize("hfov, b, d, e", [(205.0, -0.01, 4.0, -3.0), (196.0, 0.0, -6.5, 2.25)])
def test_the_circle_gives_the_lens_centre_and_hfov(hfov, b, d, e):
    """A 190-degree lens whose circle is smaller than the frame (the hfov, across the frame's
    width, is wider than the circle), shifted off the frame's centre."""
    truth = rigjax.Image(width=SIZE, height=SIZE, projection=2, hfov=hfov, b=b, d=d, e=e)
    frames = fisheye_frames(truth, 190.0)
    circle = find_image_circle(frames)
    # The circle's centre is where the axis lands: the frame's centre plus the shifts.
    np.testing.assert_allclose(circle.centre, [(SIZE - 1) / 2 + d, (SIZE - 1) / 2 + e], atol=0.1)
    assert circle.points > 600 and circle.rms < 0.5
    nominal = dataclasses.replace(truth, hfov=190.0, d=0.0, e=0.0)  # the template's lens, the truth's K2
    got_hfov, got_d, got_e, sd = lens_from_circle(nominal, circle, 190.0)
    assert got_hfov == pytest.approx(hfov, abs=0.1)
    assert (got_d, got_e) == (pytest.approx(d, abs=0.1), pytest.approx(e, abs=0.1))
    assert 0.0 < sd < 0.05 and abs(got_hfov - hfov) < 4 * sd + 0.02  # the deviation: of the edge alone


def test_a_stated_field_off_by_a_degree_moves_the_hfov_by_as_much_in_proportion():
    truth = rigjax.Image(width=SIZE, height=SIZE, projection=2, hfov=200.0)
    circle = find_image_circle(fisheye_frames(truth, 190.0, frames=1))
    hfov, *_ = lens_from_circle(truth, circle, 191.0)
    # Equidistant lens: the radius is the focal length times the angle, so hfov scales with it.
    assert hfov == pytest.approx(200.0 * 191.0 / 190.0, abs=0.1)


def test_no_edge_is_an_error_that_says_where_it_looked():
    grey = np.full((100, 100, 3), 128, np.uint8)
    with pytest.raises(rigjax.RigjaxError, match=r"edge was found on 0 of 720 rays .* radius 30.0 px"):
        find_image_circle([grey], radius=30.0)  # the search stays inside the frame: no edge at all
    with pytest.raises(rigjax.RigjaxError, match="frame 1 is 100x90, frame 0 100x100"):
        find_image_circle([grey, grey[:90]])


def test_rays_whose_drop_is_not_the_edge_leave_the_circle_where_it_is():
    """Bright wedges beyond the edge on two fifths of the rays (a lit camera body, a hand): those rays'
    drops lie 10-60 px outside the circle, and the circle is the one the other rays agree on."""
    d, e = 5.5, -7.25
    truth = rigjax.Image(width=SIZE, height=SIZE, projection=2, hfov=200.0, d=d, e=e)
    frame = fisheye_frames(truth, 190.0, frames=1)[0].copy()
    centre = np.array([(SIZE - 1) / 2 + d, (SIZE - 1) / 2 + e])
    y, x = np.mgrid[:SIZE, :SIZE].astype(float)
    angle, radius = np.arctan2(y - centre[1], x - centre[0]), np.hypot(x - centre[0], y - centre[1])
    rng = np.random.default_rng(3)
    # The edge: where the model puts a ray 95 degrees off the axis, from the axis's pixel.
    camera = rigjax.Project.new(rigjax.PanoramaLine(width=360, height=180), [truth]).cameras().take(0)
    xy, _ = rigjax.ray_to_img(camera, np.array([[np.sin(np.radians(95.0)), 0.0, np.cos(np.radians(95.0))], [0, 0, 1]]))
    edge = float(np.hypot(*(np.asarray(xy[0]) - np.asarray(xy[1]))))
    for start in rng.choice(36, 14, replace=False) * 10.0 - 180.0:  # 14 of 36 ten-degree sectors
        reach = edge + rng.uniform(10.0, 60.0)
        wedge = (np.degrees(angle) >= start) & (np.degrees(angle) < start + 10.0) & (radius < reach)
        frame[wedge & (radius >= edge - 2.0)] = 255
    circle = find_image_circle([frame])
    np.testing.assert_allclose(circle.centre, centre, atol=0.1)
    assert circle.radius == pytest.approx(edge, abs=0.35)  # the mask's edge: to the pixel it cuts
    assert 0.5 * 720 < circle.points < 0.7 * 720  # the wedges' rays left out


def test_an_edge_that_is_no_circle_is_an_error_that_says_so():
    """A bright ellipse, 300 by 560 px: its edge is found on every ray, and few of those points lie
    on any one circle (the old fit kept 5 of 36 and divided by zero, or returned a circle)."""
    ellipse = np.zeros((600, 600, 3), np.uint8)
    cv2.ellipse(ellipse, (300, 300), (150, 280), 0, 0, 360, (200, 200, 200), -1)
    for rays in (36, 720):
        with pytest.raises(rigjax.RigjaxError, match=rf"the edge found on {rays} of {rays} rays is not a circle"):
            find_image_circle([ellipse], radius=215.0, search=0.35, rays=rays)


def test_the_centres_deviation_is_what_repeated_fits_of_an_arc_scatter_by():
    """An arc of 54 degrees (108 points at 0.3 px of noise, radius 300 px) fitted 400 times: the
    centre's scatter along its worst direction against the deviation each fit reports."""
    from rigjax.calibration.circle import _deviations, _fit

    rng = np.random.default_rng(1)
    angle = np.radians(np.linspace(0.0, 54.0, 108))
    arc = 300.0 * np.stack([np.cos(angle), np.sin(angle)], axis=1)
    centres, reported = [], []
    for _ in range(400):
        points = arc + rng.normal(0.0, 0.3, arc.shape)
        centre, radius = _fit(points)
        centres.append(centre)
        reported.append(_deviations(points, centre, radius)[2])
    scatter = math.sqrt(np.linalg.eigvalsh(np.cov(np.array(centres).T)).max())
    assert np.median(reported) == pytest.approx(scatter, rel=0.15)
    assert scatter > 0.5  # an arc tells its centre poorly: far above a whole circle's few hundredths


def test_a_circle_its_frames_disagree_on_is_known_no_better_than_they_agree():
    """``circle_start`` (the motion calibration's start): two frames of one lens, the second moved 3 px
    to the right (as a frame whose rim shows something else would place it): the centre's deviation
    grows to the frames' disagreement; frames that agree leave it at the fit's few hundredths."""
    from rigjax.calibration.motion import circle_start

    truth = rigjax.Image(width=SIZE, height=SIZE, projection=2, hfov=200.0, d=4.0, e=-3.0)
    frames = fisheye_frames(truth, 190.0)
    nominal = dataclasses.replace(truth, hfov=190.0, d=0.0, e=0.0)
    _, agreed, line = circle_start(nominal, frames, 190.0)
    assert agreed.centre_sd < 0.1 and "the frames' own within" in line
    moved = [frames[0], np.roll(frames[1], 3, axis=1)]
    _, circle, _ = circle_start(nominal, moved, 190.0)
    apart = [find_image_circle([frame]).centre for frame in moved]
    assert np.linalg.norm(apart[1] - apart[0]) == pytest.approx(3.0, abs=0.1)
    assert circle.centre_sd >= 1.4  # at least half the frames' 3 px from any centre between them
