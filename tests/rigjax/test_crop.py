"""Hugin's crops (an ``i`` line's ``S l,r,t,b``): read, written back, and honoured by rigjax render
as Hugin's ``nona`` honours them. The form of Hugin's templates for dual-fisheye cameras: both
``i`` lines name the whole side-by-side frame, each lens's centre shifted (``d``) into its half and
its crop bounding its circle."""

from __future__ import annotations

import shutil
import subprocess

import numpy as np
import pytest

import rigjax
from rigjax.errors import PtoError
from rigjax.rendering.remap import pano_maps

# An 800 x 400 side-by-side frame: two 190-degree circular fisheyes of 400 px, back to back. The
# hfov is Hugin's, across the whole frame's width: 190 degrees over 400 px is 380 over 800.
DUAL = """\
p f2 w720 h360 v360  E0 R0 n"TIFF_m c:NONE r:UNCROP"
m g1 i0 f0 m2 p0.00784314
i w800 h400 f2 v380 Ra0 Rb0 Rc0 Rd0 Re0 Eev0 Er1 Eb1 r0.5 p-1 y0 TrX0 TrY0 TrZ0 Tpy0 Tpp0 j0 a0 b-0.01 c0 d-203 e4 g0 t0 Va1 Vb0 Vc0 Vd0 Vx0 Vy0  S-3,395,6,395 Vm5 n"frame.png"
i w800 h400 f2 v=0 Ra0 Rb0 Rc0 Rd0 Re0 Eev0 Er1 Eb1 r-0.5 p1 y180 TrX0 TrY0 TrZ0 Tpy0 Tpp0 j0 a0 b=0 c0 d197 e-2 g0 t0 Va1 Vb0 Vc0 Vd0 Vx0 Vy0  S401,797,3,399 Vm5 n"frame.png"
"""


def test_crops_are_read_and_written_back_as_they_were():
    project = rigjax.parse_project(DUAL)
    assert [image.crop for image in project.images] == [(-3, 395, 6, 395), (401, 797, 3, 399)]
    assert project.to_text().startswith(DUAL)  # unchanged, byte for byte
    # A changed crop is written in its place; one taken away leaves no token behind; a new image's is written.
    left, right = project.images
    changed = project.replace(images=(left.replace(crop=(0, 400, 0, 400)), right.replace(crop=None)))
    lines = changed.to_text().splitlines()
    assert lines[2] == DUAL.splitlines()[2].replace("S-3,395,6,395", "S0,400,0,400")
    assert lines[3] == DUAL.splitlines()[3].replace("  S401,797,3,399", "")
    fresh = rigjax.Project.new(project.panorama, project.images)
    assert [image.crop for image in rigjax.parse_project(fresh.to_text()).images] == [left.crop, right.crop]


@pytest.mark.parametrize(
    "token, message",
    [
        ("S1,2,3", r"<text>:3: token 'S1,2,3': the crop 'S' takes left,right,top,bottom, found '1,2,3'"),
        ("S1,2,a,4", r"<text>:3: token 'S1,2,a,4': the crop 'S' needs"),
    ],
)
def test_a_bad_crop_names_its_line(token, message):
    with pytest.raises(PtoError, match=message):
        rigjax.parse_project(DUAL.replace("S-3,395,6,395", token))


def test_crops_read_as_hugin_reads_them_and_are_checked_when_set():
    # An empty crop is none, its token kept; libpano's C reads as S, and S comes first where both are.
    empty = rigjax.parse_project(DUAL.replace("S-3,395,6,395", "S5,3,0,10"))
    assert empty.images[0].crop is None and empty.to_text().startswith(DUAL.replace("S-3,395,6,395", "S5,3,0,10"))
    cut = rigjax.parse_project(DUAL.replace("S-3,395,6,395", "C0,400,0,400"))
    assert cut.images[0].crop == (0, 400, 0, 400)
    changed = cut.replace(images=(cut.images[0].replace(crop=(1, 399, 1, 399)), cut.images[1]))
    assert " S1,399,1,399 " in changed.to_text().splitlines()[2] and " C0" not in changed.to_text()
    both = rigjax.parse_project(DUAL.replace("S-3,395,6,395", "C0,400,0,400 S2,398,2,398"))
    assert both.images[0].crop == (2, 398, 2, 398)
    # Set in Python: whole pixels, left < right and top < bottom, kept as a tuple of ints.
    image = empty.images[0]
    assert image.replace(crop=np.array([0, 400, 0, 400])).crop == (0, 400, 0, 400)
    with pytest.raises(rigjax.RigjaxError, match=r"crop: expected left < right and top < bottom, got \(5, 3, 0, 10\)"):
        image.replace(crop=(5, 3, 0, 10))
    with pytest.raises(rigjax.RigjaxError, match="crop: expected .* whole pixels"):
        image.replace(crop=(0.5, 400, 0, 400))
    assert [im.circular_crop for im in rigjax.parse_project(DUAL.replace(" f2 v", " f3 v")).images] == [False, False]


def _distance_to_crop_edge(xy: np.ndarray, image: rigjax.Image) -> np.ndarray:
    """How far (px) each source point lies from its image's crop edge (the inscribed circle of a
    circular fisheye's crop, else the rectangle)."""
    left, right, top, bottom = image.crop
    half = np.array([(right - left) / 2.0, (bottom - top) / 2.0])
    if image.projection == 2:  # the circle about ((l + r) / 2, (t + b) / 2)
        offset = xy - np.array([(left + right) / 2.0, (top + bottom) / 2.0])
        return np.abs(np.linalg.norm(offset, axis=-1) - half.min())
    # the rectangle of whole pixels l .. r - 1, t .. b - 1: from l - 0.5 to r - 0.5
    offset = xy - np.array([(left + right - 1) / 2.0, (top + bottom - 1) / 2.0])
    return np.min(np.abs(np.abs(offset) - half), axis=-1)


@pytest.mark.skipif(shutil.which("nona") is None, reason="Hugin's nona is not installed (apt-get install hugin-tools)")
@pytest.mark.parametrize("projection", [2, 3])
def test_what_each_image_covers_is_what_nona_covers(tmp_path, projection):
    """Each image remapped alone by nona (its alpha) and by rigjax (the valid pixels), through a
    circular fisheye's crop circle (f2) or a full-frame fisheye's crop rectangle (f3): the same
    canvas pixels, but those whose source point lies within a pixel of the crop's edge (nona draws
    it through its interpolated mask)."""
    import cv2

    text = DUAL if projection == 2 else DUAL.replace(" f2 v", " f3 v")
    (tmp_path / "dual.pto").write_text(text)
    rng = np.random.default_rng(0)
    cv2.imwrite(str(tmp_path / "frame.png"), rng.integers(40, 215, (400, 800, 3), dtype=np.uint8))
    subprocess.run(
        ["nona", "-m", "TIFF_m", "-o", str(tmp_path / "out"), str(tmp_path / "dual.pto")],
        check=True,
        capture_output=True,
    )
    project = rigjax.load_project(tmp_path / "dual.pto")
    cameras = project.cameras()
    for k, image in enumerate(project.images):
        alpha = cv2.imread(str(tmp_path / f"out{k:04d}.tif"), cv2.IMREAD_UNCHANGED)[..., 3] > 0
        _, valid = pano_maps(
            cameras.take(k),
            project.canvas(),
            circle=projection == 2,
            crop=image.crop,
            circular_crop=image.circular_crop,
        )
        source, in_frame = pano_maps(cameras.take(k), project.canvas())  # every pixel's source point
        assert alpha.sum() > 100_000  # a lens's half of the sphere, not an empty image
        # nona draws the crop's edge through its interpolated alpha: it covers up to a pixel beyond.
        clear = in_frame & (_distance_to_crop_edge(source, image) > 1.0)
        assert np.array_equal(alpha[clear], valid[clear])
        assert (alpha != valid).mean() < 0.01
    # The whole render: a canvas pixel is covered where an image's crop holds it.
    _, covered = rigjax.render(project)
    nona_covered = np.zeros_like(covered)
    for k in range(2):
        nona_covered |= cv2.imread(str(tmp_path / f"out{k:04d}.tif"), cv2.IMREAD_UNCHANGED)[..., 3] > 0
    assert np.mean(covered != nona_covered) < 0.01
