"""rigjax's transforms against Hugin's pano_trafo: recorded golden data, and live when installed."""

from __future__ import annotations

import subprocess

import numpy as np
import pytest
from golden import GOLDEN, PROJECTS, comparable, load_golden

import rigjax

TOLERANCE_PX = 0.01


def test_golden_set_covers_the_model():
    projects = [rigjax.load_project(GOLDEN / f"{name}.pto") for name in PROJECTS]
    images = [image for project in projects for image in project.images]
    assert len(projects) >= 12
    assert {image.projection for image in images} >= set(rigjax.Projection)
    assert any(image.width < image.height for image in images) and any(image.width > image.height for image in images)
    for letter in "abcde":
        assert any(image.value(letter) != 0 for image in images), letter
    assert any(abs(image.pitch) > 80 for image in images) and any(abs(image.roll) > 150 for image in images)
    assert any(image.links for image in images)


def _compare(name, direction, image, xy_in, hugin_out):
    project = rigjax.load_project(GOLDEN / f"{name}.pto")
    out, valid = rigjax.transform_points(project.cameras(), project.canvas(), image, xy_in, reverse=direction == "r")
    # pano_trafo prints nan, or -1 -1, where libpano13 cannot map a point.
    hugin_defined = np.all(np.isfinite(hugin_out), axis=1) & ~np.all(hugin_out == -1.0, axis=1)
    size = np.array([[project.images[k].width, project.images[k].height] for k in image])
    both = valid & comparable(size, direction, hugin_out)
    err = np.abs(out - hugin_out).max(axis=1)
    # Rectilinear and orthographic lenses see at most a hemisphere: a quarter is comparable.
    assert both.sum() >= 0.25 * len(image), f"{name}: only {both.sum()} of {len(image)} points comparable"
    worst = np.argmax(np.where(both, err, 0))
    assert err[both].max() <= TOLERANCE_PX, (
        f"{name} {direction}: image {image[worst]} {xy_in[worst]} -> rigjax {out[worst]}, Hugin {hugin_out[worst]}"
    )
    return out, valid, hugin_defined


@pytest.mark.parametrize("name", PROJECTS)
@pytest.mark.parametrize("direction", ["f", "r"])
def test_matches_golden_pano_trafo(name, direction):
    golden = load_golden(name)[direction]
    out, valid, hugin_defined = _compare(name, direction, *golden)
    # Where rigjax flags a point, Hugin has no meaningful answer either: nan, a point thrown far
    # outside the image (libpano13's x1000 clamp, rays behind the lens), or, straight behind a
    # fisheye, an arbitrary point of the circle r = pi f. Every point Hugin maps into the frame
    # is valid in rigjax.
    if direction == "r":
        project = rigjax.load_project(GOLDEN / f"{name}.pto")
        size = np.array([[project.images[k].width, project.images[k].height] for k in golden.image])
        inside = hugin_defined & np.all((golden.xy_out >= -0.5) & (golden.xy_out <= size - 0.5), axis=1)
        assert not np.any(inside & ~valid), f"{name}: rigjax rejects points that Hugin maps into the image"


def test_invalid_points_are_flagged_where_hugin_returns_garbage():
    # Barrel distortion so strong that the polynomial turns back inside the frame (reference §1).
    fwd = load_golden("ff_strong_barrel")["f"]
    _, valid, _ = _compare("ff_strong_barrel", "f", *fwd)
    assert 0 < (~valid).sum() < len(valid)
    # Rays behind a rectilinear camera.
    rev = load_golden("rect_landscape_abcde")["r"]
    _, valid, _ = _compare("rect_landscape_abcde", "r", *rev)
    assert 0 < (~valid).sum() < len(valid)


@pytest.mark.hugin
@pytest.mark.parametrize("name", PROJECTS)
def test_matches_live_pano_trafo(name, hugin_tools):
    """Fresh random points (not those recorded) through the installed pano_trafo."""
    project = rigjax.load_project(GOLDEN / f"{name}.pto")
    rng = np.random.default_rng(1234)
    for direction in "fr":
        image = rng.integers(0, len(project.images), 300)
        if direction == "f":
            size = np.array([[im.width, im.height] for im in project.images])[image]
        else:
            size = np.array([[project.panorama.width, project.panorama.height]] * len(image))
        xy = rng.uniform(0.0, 1.0, (len(image), 2)) * size - 0.5  # the whole image or canvas
        text = "".join(f"{k} {x:.9f} {y:.9f}\n" for k, (x, y) in zip(image, xy))
        cmd = ["pano_trafo"] + (["-r"] if direction == "r" else []) + [str(GOLDEN / f"{name}.pto")]
        lines = subprocess.run(cmd, input=text, capture_output=True, text=True, check=True).stdout.split("\n")
        hugin = np.array([[float(v) for v in line.split()] for line in lines[: len(image)]])
        _compare(name, direction, image, np.round(xy, 9), hugin)
