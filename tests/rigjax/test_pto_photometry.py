"""Hugin's photometric model (rigjax.camera.photometry): exposure, white balance, radial vignetting;
read from and written to .pto projects, and undone by rigjax render."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

import rigjax
from rigjax.camera.photometry import image_gain, to_panorama, vignetting

GOLDEN = Path(__file__).parent / "data" / "golden_photometry"
FLAT_RGB = np.array([0.3, 0.5, 0.7])  # the golden project's image, the same value everywhere


def hugin_vignetting(coefficients, centre_shift, size, xy):
    """Hugin's ResponseTransform::calcVigFactor (radial mode), written as Hugin loops it: the centre
    ((w - 1) / 2, (h - 1) / 2) + (Vx, Vy), the radius scaled by 1 / sqrt(w^2 / 4 + h^2 / 4)."""
    w, h = size
    d = (np.asarray(xy, float) - ((w - 1) / 2.0 + centre_shift[0], (h - 1) / 2.0 + centre_shift[1])) / np.sqrt(
        w * w / 4.0 + h * h / 4.0
    )
    r2 = d[..., 0] ** 2 + d[..., 1] ** 2
    vig, r = coefficients[0] + 0.0 * r2, r2
    for coefficient in coefficients[1:]:
        vig = vig + coefficient * r
        r = r * r2
    return vig


def photometric_image(**values):
    fields = dict(
        exposure_value=1.25,
        white_balance_red=1.3,
        white_balance_blue=0.8,
        vignetting_a=1.1,
        vignetting_b=-0.45,
        vignetting_c=0.12,
        vignetting_d=-0.04,
        vignetting_x=6.0,
        vignetting_y=-3.0,
    )
    return rigjax.Image(width=60, height=40, projection=0, hfov=100.0, **(fields | values))


def test_gain_is_hugins_closed_form():
    image = photometric_image()
    xy = np.random.default_rng(0).uniform([-5, -5], [65, 45], size=(500, 2))
    vig = hugin_vignetting((1.1, -0.45, 0.12, -0.04), (6.0, -3.0), (60, 40), xy)
    np.testing.assert_allclose(vignetting(image, xy), vig, rtol=1e-14)
    # SrcPanoImage::getExposure: 1 / 2^Eev; the white balance multiplies red and blue.
    expected = vig[:, None] / 2.0**1.25 * np.array([1.3, 1.0, 0.8])
    np.testing.assert_allclose(image_gain(image, xy), expected, rtol=1e-14)
    # At the vignetting centre only Va and the exposure are left.
    assert vignetting(image, np.array([[29.5 + 6.0, 19.5 - 3.0]]))[0] == pytest.approx(1.1, abs=1e-15)
    values = np.full((500, 3), 100.0)
    np.testing.assert_allclose(to_panorama(values, image, xy, 0.5), 100.0 * 2.0**-0.5 / expected, rtol=1e-14)


def _model_of_golden():
    """rigjax's panorama of the golden project's flat image: each covered pixel's image position by
    rigjax's geometry (which matches pano_trafo, test_golden_hugin), its value by the model."""
    project = rigjax.load_project(GOLDEN / "flat.pto")
    height, width = project.panorama.height, project.panorama.width
    x, y = np.meshgrid(np.arange(width, dtype=float), np.arange(height, dtype=float))
    pano_xy = np.stack([x.ravel(), y.ravel()], axis=1)
    image_xy, valid = rigjax.transform_points(
        project.cameras(), project.canvas(), np.zeros(len(pano_xy), int), pano_xy, reverse=True
    )
    model = to_panorama(FLAT_RGB, project.images[0], np.asarray(image_xy), project.panorama.exposure_value)
    return project, np.asarray(model).reshape(height, width, 3), np.asarray(valid).reshape(height, width)


def test_the_model_is_what_hugins_nona_renders():
    """Recorded from nona (tests/rigjax/data/make_golden_photometry.py): a float image, linear
    response, Eev 1.25, Er 1.3, Eb 0.8, Va..Vd 1.1 / -0.45 / 0.12 / -0.04, the centre shifted by
    (6, -3) px, the panorama at E 0.5."""
    nona = np.load(GOLDEN / "flat_nona.npz")["rgba"]
    project, model, valid = _model_of_golden()
    # Inside the image by a pixel: nona's edge pixels blend with the outside.
    inner = valid & (nona[..., 3] > 0)
    inner &= np.roll(inner, 1, 0) & np.roll(inner, -1, 0) & np.roll(inner, 1, 1) & np.roll(inner, -1, 1)
    assert inner.sum() > 300
    np.testing.assert_allclose(model[inner], nona[..., :3][inner], rtol=2e-5)
    # The vignetting reaches 30 % across the image: a test that a constant would fail.
    assert model[inner][:, 1].max() / model[inner][:, 1].min() > 1.3


@pytest.mark.skipif(shutil.which("nona") is None, reason="Hugin's nona is not installed (apt-get install hugin-tools)")
def test_the_golden_data_is_what_nona_renders_now(tmp_path):
    import cv2

    subprocess.run(["nona", "-o", str(tmp_path / "out"), "-m", "TIFF_m", str(GOLDEN / "flat.pto")], check=True)
    out = cv2.imread(str(tmp_path / "out0000.tif"), cv2.IMREAD_UNCHANGED)
    np.testing.assert_allclose(out[..., 2::-1], np.load(GOLDEN / "flat_nona.npz")["rgba"][..., :3], rtol=1e-6)


def test_photometric_letters_are_read_linked_and_written_back(tmp_path):
    text = (GOLDEN / "flat.pto").read_text()
    # A second image that links its vignetting to the first and has no Eev (Hugin's default 0).
    second = (
        next(line for line in text.splitlines() if line.startswith("i "))
        .replace("Eev1.25 ", "")
        .replace("Va1.1 Vb-0.45 Vc0.12 Vd-0.04", "Va=0 Vb=0 Vc=0 Vd=0")
    )
    path = tmp_path / "two.pto"
    path.write_text(text.replace("\n# specify", f"{second}\n\n# specify"))
    project = rigjax.load_project(path)
    first, linked = project.images
    assert (first.exposure_value, first.white_balance_red, first.white_balance_blue) == (1.25, 1.3, 0.8)
    assert (linked.exposure_value, linked.vignetting_b, linked.links["Vb"]) == (0.0, -0.45, 0)
    assert project.panorama.exposure_value == 0.5
    project.save(tmp_path / "same.pto")
    # Unchanged, byte for byte (the writer adds Hugin's optimiser switches after the last line).
    assert (tmp_path / "same.pto").read_text().startswith(path.read_text())
    changed = project.replace(images=(first.replace(exposure_value=-0.5, vignetting_y=2.0), linked))
    changed.save(tmp_path / "changed.pto")
    lines = (tmp_path / "changed.pto").read_text().splitlines()
    assert lines[6] == next(line for line in path.read_text().splitlines() if line.startswith("i ")).replace(
        "Eev1.25", "Eev-0.5"
    ).replace("Vy-3", "Vy2")
    assert "Rt1" in lines[6] and "Vm5" in lines[6]  # what rigjax does not read stays as written
    # A project written from scratch carries the values too, and reads back the same.
    fresh = rigjax.Project.new(changed.panorama, changed.images[:1])
    fresh.save(tmp_path / "fresh.pto")
    assert rigjax.load_project(tmp_path / "fresh.pto").images[0] == changed.images[0]
    assert " E0.5 " in (tmp_path / "fresh.pto").read_text()


def test_render_undoes_exposure_white_balance_and_vignetting():
    """A flat grey scene photographed through the model renders flat at the panorama's exposure."""
    image = photometric_image(vignetting_a=1.0, exposure_value=0.5)
    x, y = np.meshgrid(np.arange(60, dtype=float), np.arange(40, dtype=float))
    xy = np.stack([x, y], axis=-1)
    vig = hugin_vignetting((1.0, -0.45, 0.12, -0.04), (6.0, -3.0), (60, 40), xy)
    scene = 150.0
    pixels = np.clip(np.round(scene * vig[..., None] / 2.0**0.5 * np.array([1.3, 1.0, 0.8])), 0, 255).astype(np.uint8)
    project = rigjax.Project.new(rigjax.PanoramaLine(width=180, height=90), [image])
    pano, covered = rigjax.render(project, [pixels], blend="none")
    inner = (
        covered & np.roll(covered, 1, 0) & np.roll(covered, -1, 0) & np.roll(covered, 1, 1) & np.roll(covered, -1, 1)
    )
    assert inner.sum() > 100
    assert np.abs(pano[inner].astype(float) - scene).max() <= 2.0
    # Without the model the same image is as uneven as its vignetting.
    plain, _ = rigjax.render(
        project.replace(images=(rigjax.Image(width=60, height=40, projection=0, hfov=100.0),)), [pixels], blend="none"
    )
    assert np.ptp(plain[inner][:, 1].astype(float)) > 20
