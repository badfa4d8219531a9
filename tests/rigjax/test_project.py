""".pto projects: lossless round trips, edits, links, and errors that name file, line and token."""

from __future__ import annotations

import gc
import re
import subprocess

import numpy as np
import pytest
from golden import GOLDEN, PROJECTS

import rigjax
from rigjax import synthetic
from rigjax.pto.records import Mask

# A project with everything rigjax must keep: Hugin comments, photometric tokens, a crop, a quoted
# name with spaces, links, masks, line control points, a control point with an unknown token,
# an unknown line type, blank lines, double spaces, and lines of another program.
RICH = """\
# hugin project file
#hugin_ptoversion 2
p f2 w3000 h1500 v360  k0 E12.5 R0 S100,2900,200,1300 n"TIFF_m c:LZW r:CROP"
m i0 g1 f0

# image lines
#-hugin  cropFactor=1
i w4000 h3000 f3 v165.25 Ra0 Rb0 Rc0 Rd0 Re0 Eev12.5 Er1 Eb1 r-1.5 p2.25 y0 TrX0 TrY0 TrZ0 Tpy0 Tpp0 j0 a0.001 b-0.02 c0.003 d10 e-5 g0 t0 Va1 Vb0.1 Vc0 Vd0 Vx0 Vy0  Vm5 S0,4000,0,3000 n"front lens.jpg"
#-hugin  cropFactor=1 disabled
i w4000 h3000 f3 v=0 Ra=0 Rb=0 Rc=0 Rd=0 Re=0 Eev12.5 Er1 Eb1 r0.75 p-1.25 y90.5 TrX0 TrY0 TrZ0 Tpy0 Tpp0 j0 a=0 b=0 c=0 d=0 e=0 g0 t0 Va=0 Vb=0 Vc=0 Vd=0 Vx=0 Vy=0  Vm5 n"right.jpg"
i w4000 h3000 f3 v=1 Ra0 Rb0 Rc0 Rd0 Re0 Eev12.5 Er1 Eb1 r0 p0 y180 TrX0 TrY0 TrZ0 Tpy0 Tpp0 j0 a0 b=1 c0 d0 e0 g0 t0 Va1 Vb0 Vc0 Vd0 Vx0 Vy0  Vm5 u10 n"back.jpg"

# specify variables that should be optimized
v v0
v b0
v y1
v p1
v r1
v Eev1
v

# control points
c n0 N1 x3000.5 y1500.25 X1000.125 Y1490 t0
c n0 N1 x3100 y400 X1100 Y420 t0 q7
c n1 N2 x3500 y2900.5 X400 Y2950 t1
c n0 N2 x10 y20 X30 Y40 t3
c n0 N2 x50 y60 X70 Y80 t3

# masks
k i0 t0 p"0 0 100 0 100 100 0 100"
k i2 t1 p"10.5 20 300 20 300 400"
z something only another program reads

#hugin_optimizeReferenceImage 0
#hugin_blender enblend
#hugin_optimizerMasterSwitch 0
#hugin_optimizerPhotoMasterSwitch 0
"""


@pytest.fixture
def rich(tmp_path):
    path = tmp_path / "rich.pto"
    path.write_text(RICH)
    return path


def _same_geometry(a: rigjax.Project, b: rigjax.Project) -> None:
    assert a.panorama == b.panorama
    assert a.images == b.images
    assert a.control_points.equals(b.control_points)
    assert a.variables == b.variables
    assert len(a.masks) == len(b.masks) and all(m.equals(n) for m, n in zip(a.masks, b.masks))


def test_reads_what_hugin_means(rich):
    p = rigjax.load_project(rich)
    assert p.panorama == rigjax.PanoramaLine(width=3000, height=1500, hfov=360.0, projection=2, exposure_value=12.5)
    front, right, back = p.images
    assert (front.width, front.height, front.projection, front.filename) == (4000, 3000, 3, "front lens.jpg")
    assert (front.hfov, front.a, front.b, front.c, front.d, front.e) == (165.25, 0.001, -0.02, 0.003, 10.0, -5.0)
    assert (front.yaw, front.pitch, front.roll) == (0.0, 2.25, -1.5)
    # Links carry the linked value; a chain (v of image 2 -> 1 -> 0) resolves to its root.
    assert right.hfov == back.hfov == 165.25 and right.links["v"] == 0 and back.links["v"] == 0
    assert right.b == back.b == -0.02 and back.links["b"] == 0
    assert back.a == 0.0 and "a" not in back.links
    assert p.variables == tuple(
        rigjax.OptVariable(n, k) for n, k in [("v", 0), ("b", 0), ("y", 1), ("p", 1), ("r", 1), ("Eev", 1)]
    )
    cps = p.control_points
    assert len(cps) == 5 and cps.image_a.tolist() == [0, 0, 1, 0, 0] and cps.kind.tolist() == [0, 0, 1, 3, 3]
    np.testing.assert_array_equal(cps.xy_a[0], [3000.5, 1500.25])
    np.testing.assert_array_equal(cps.xy_b[0], [1000.125, 1490.0])
    assert cps.extra[1] == "q7"
    assert [(m.image, m.kind, m.polygon.shape) for m in p.masks] == [(0, 0, (4, 2)), (2, 1, (3, 2))]


def test_unchanged_project_is_written_back_byte_for_byte(rich, tmp_path):
    out = tmp_path / "out.pto"
    rigjax.load_project(rich).save(out)
    assert out.read_text() == RICH


@pytest.mark.parametrize("name", PROJECTS)
def test_golden_projects_round_trip(name, tmp_path):
    text = (GOLDEN / f"{name}.pto").read_text()
    p = rigjax.load_project(GOLDEN / f"{name}.pto")
    assert p.to_text() == text
    (tmp_path / "p.pto").write_text(p.to_text())
    _same_geometry(p, rigjax.load_project(tmp_path / "p.pto"))


def test_the_master_switch_is_kept_until_the_v_lines_change(tmp_path):
    text = RICH.replace("#hugin_optimizerMasterSwitch 0", "#hugin_optimizerMasterSwitch 14")
    text = text.replace("#hugin_optimizerPhotoMasterSwitch 0", "#hugin_optimizerPhotoMasterSwitch 21")
    p = rigjax.parse_project(text)
    assert p.optimizer_switch == 14
    assert p.to_text() == text  # an unedited project keeps the user's optimiser presets
    moved = p.replace(images=(p.images[0].replace(yaw=3.0), *p.images[1:]))
    assert "#hugin_optimizerMasterSwitch 14\n" in moved.to_text()  # new values, the same v lines
    changed = p.replace(variables=p.variables[:2]).to_text()  # the v lines decide from now on
    assert "#hugin_optimizerMasterSwitch 0\n" in changed and "#hugin_optimizerPhotoMasterSwitch 0\n" in changed
    # Files without the switches get both, at the end.
    bare = "\n".join(line for line in RICH.splitlines() if "MasterSwitch" not in line) + "\n"
    assert rigjax.parse_project(bare).to_text().splitlines()[-2:] == [
        "#hugin_optimizerMasterSwitch 0",
        "#hugin_optimizerPhotoMasterSwitch 0",
    ]


def test_edited_values_are_written_with_15_digits_and_the_rest_kept(rich, tmp_path):
    p = rigjax.load_project(rich)
    front = p.images[0].replace(hfov=163.123456789012345678, b=-0.0212345678901234567)
    right = p.images[1].replace(yaw=1 / 3, hfov=front.hfov, b=front.b)
    back = p.images[2].replace(hfov=front.hfov, b=front.b, pitch=-0.0)
    edited = p.replace(images=(front, right, back), variables=p.variables[:2])
    out = tmp_path / "edited.pto"
    edited.save(out)
    text = out.read_text()
    lines = [""] + text.splitlines()  # 1-based, as in the file
    assert "v163.123456789012" in lines[8] and "b-0.0212345678901235" in lines[8]
    assert "y0.333333333333333" in lines[10] and "v=0" in lines[10] and "b=0" in lines[10]
    assert "v=0" in lines[11] and "b=0" in lines[11]  # changed values: links written as Hugin does
    assert lines[8].endswith('Vm5 S0,4000,0,3000 n"front lens.jpg"') and " u10 " in lines[11]
    assert [line for line in lines if line.startswith("v")] == ["v v0", "v b0", "v"]
    for keep in [
        "p f2 w3000 h1500 v360  k0 E12.5 R0 S100,2900,200,1300",
        "m i0 g1 f0",
        "z something only",
        "c n0 N1 x3100 y400 X1100 Y420 t0 q7",
        'k i2 t1 p"10.5 20 300 20 300 400"',
        "#-hugin  cropFactor=1 disabled",
    ]:
        assert keep in text
    back_in = rigjax.load_project(out)
    assert back_in.images[0].hfov == float("163.123456789012")
    assert back_in.images[1].yaw == float("0.333333333333333")
    assert back_in.images[2].pitch == 0.0 and back_in.images[2].links == p.images[2].links


def test_new_values_missing_from_a_line_are_added(rich):
    p = rigjax.load_project(rich)
    line = 'i w100 h80 f0 n"x.jpg"'
    q = rigjax.parse_project(
        RICH.replace("#-hugin  cropFactor=1 disabled\n", line + "\n#-hugin  cropFactor=1 disabled\n")
    )
    assert q.images[1].hfov == 51.0  # Hugin's default hfov
    edited = q.replace(images=(q.images[0], q.images[1].replace(yaw=12.5, b=0.01)) + q.images[2:])
    new_line = next(line for line in edited.to_text().splitlines() if line.startswith("i w100"))
    assert new_line == 'i w100 h80 f0 b0.01 y12.5 n"x.jpg"'
    assert len(p.images) == 3


def test_control_point_edits_are_rendered(rich):
    p = rigjax.load_project(rich)
    cps = p.control_points
    keep = np.array([True, True, False, True, True])
    pruned = rigjax.ControlPoints(
        cps.image_a[keep],
        cps.image_b[keep],
        cps.xy_a[keep],
        cps.xy_b[keep],
        cps.kind[keep],
        tuple(e for e, k in zip(cps.extra, keep) if k),
    )
    text = p.replace(control_points=pruned).to_text()
    assert [line for line in text.splitlines() if line.startswith("c ")] == [
        "c n0 N1 x3000.5 y1500.25 X1000.125 Y1490 t0",
        "c n0 N1 x3100 y400 X1100 Y420 t0 q7",
        "c n0 N2 x10 y20 X30 Y40 t3",
        "c n0 N2 x50 y60 X70 Y80 t3",
    ]


def test_records_added_to_a_file_without_them_are_written(tmp_path):
    text = "p f2 w3600 h1800 v360\ni w1440 h1080 f3 v123 y0 p0 r0\ni w1440 h1080 f3 v123 y90 p0 r0\n"
    p = rigjax.parse_project(text)
    cps = rigjax.ControlPoints([0], [1], [[1400.0, 500.0]], [[40.0, 510.0]], [0])
    mask = Mask(1, 0, np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 10.0]]))
    q = p.replace(control_points=cps, variables=(rigjax.OptVariable("y", 1),), masks=(mask,))
    (tmp_path / "q.pto").write_text(q.to_text())
    back = rigjax.load_project(tmp_path / "q.pto")
    assert back.control_points.equals(cps) and back.variables == q.variables and back.masks[0].equals(mask)
    assert back.to_text().startswith(text)


def test_new_project_round_trips(tmp_path):
    p = synthetic.control_points_from_truth(synthetic.cube_rig(orientation_jitter_deg=2, seed=3), 300)
    out = tmp_path / "new.pto"
    p.save(out)
    q = rigjax.load_project(out)
    assert len(q.images) == 6 and len(q.control_points) > 50
    for a, b in zip(p.images, q.images):
        for letter in ("v", "b", "y", "p", "r"):
            assert b.value(letter) == float(f"{a.value(letter):.15g}")
    np.testing.assert_allclose(q.control_points.xy_a, p.control_points.xy_a, rtol=1e-14)
    assert q.to_text() == out.read_text()


def test_cameras_and_back(rich):
    p = rigjax.load_project(rich)
    cams = p.cameras()
    assert cams.hfov.shape == (3,) and cams.hfov.dtype == np.float64
    np.testing.assert_array_equal(cams.yaw, [0.0, 90.5, 180.0])
    moved = cams._replace(yaw=cams.yaw + 1.0, hfov=cams.hfov * 0 + 150.0)
    q = p.with_cameras(moved)
    assert [im.yaw for im in q.images] == [1.0, 91.5, 181.0] and q.images[2].hfov == 150.0
    with pytest.raises(rigjax.RigjaxError, match=r"image 1 links 'v' to image 0"):
        p.with_cameras(cams._replace(hfov=np.array([150.0, 151.0, 150.0])))


def test_unmodelled_geometry_is_refused():
    p = rigjax.parse_project(RICH.replace("g0 t0 Va1 Vb0.1", "g0.5 t0 Va1 Vb0.1"))
    with pytest.raises(rigjax.UnsupportedError, match=r"image 0: g=0.5 is not modelled"):
        p.cameras()
    with pytest.raises(rigjax.UnsupportedError, match=r"panorama projection f0"):
        rigjax.parse_project(RICH.replace("p f2 w3000", "p f0 w3000")).canvas()


def test_odd_equirectangular_width_is_rounded_up_like_hugin():
    p = rigjax.parse_project(RICH.replace("p f2 w3000", "p f2 w3001"))
    assert float(p.canvas().width) == 3002.0
    assert "p f2 w3001 " in p.to_text()


# ---------------------------------------------------------------------------------------------
# Bad input: each error names the file, the line and the token.
BAD = [
    ("f3 v165.25", "f3 vabc", r"rich\.pto:8: token 'vabc': 'v' \(hfov\) needs a number, found 'abc'"),
    ("i w4000 h3000 f3 v165", "i w4000 h3000 f7 v165", r":8: token 'f7': unknown lens type f7"),
    ("v=0 Ra=0", "v=5 Ra=0", r":10: token 'v=5': link to image 5, the project has 3 images"),
    ("v=0 Ra=0", "v=1 Ra=0", r":10: token 'v=1': image 1 links 'v' to itself"),
    ("p f2 w3000 h1500 v360  k0", "p f2 w3000 h1500 vnan  k0", r":3: token 'vnan': panorama hfov 'v' needs a number"),
    ("r-1.5 p2.25", "r-1.5 pnan", r":8: token 'pnan': 'p' \(pitch\) needs a number, found 'nan'"),
    ("y0 TrX0", "y1e999 TrX0", r":8: token 'y1e999': 'y' \(yaw\) is out of range"),
    ('n"back.jpg"', 'n"back.jpg', r":11: token 'n\"back.jpg': unterminated quoted string"),
    ("c n0 N1 x3100 y400", "c n0 N7 x3100 y400", r":24: token 'N7': control point refers to image 7"),
    ("c n0 N1 x3100 y400", "c n0 N1 x3100", r":24: the control point has no 'y'"),
    ("c n0 N1 x3100 y400", "c n0 N1 x3,1 y400", r":24: token 'x3,1': 'x' needs a number"),
    ("v y1\n", "v y9\n", r":16: token 'y9': variable refers to image 9"),
    ("v y1\n", "v zz1\n", r":16: token 'zz1': unknown variable 'zz'"),
    ("k i2 t1", "k i5 t1", r":31: token 'i5': mask refers to image 5"),
    ("i w4000 h3000 f3 v165", "i h3000 f3 v165", r":8: the image line has no 'w'"),
    ("r-1.5 p2.25", "r-1.5 p2.25 p3", r":8: token 'p3': 'p' is given twice"),
    ("p f2 w3000 h1500 v360 ", "p f2 w3000 v360 ", r":3: the panorama line has no 'h'"),
    ('p f2 w3000 h1500 v360  k0 E12.5 R0 S100,2900,200,1300 n"TIFF_m c:LZW r:CROP"\n', "", r"no panorama line"),
]


@pytest.mark.parametrize("old, new, message", BAD, ids=[b[1][:24] for b in BAD])
def test_malformed_input_names_file_line_and_token(tmp_path, old, new, message):
    assert old in RICH
    path = tmp_path / "rich.pto"
    path.write_text(RICH.replace(old, new, 1))
    with pytest.raises(rigjax.PtoError, match=message) as info:
        rigjax.load_project(path)
    assert str(path) in str(info.value)


def test_link_cycle_is_an_error():
    text = RICH.replace("v165.25 Ra0", "v=2 Ra0").replace("v=1 Ra0", "v=0 Ra0")
    with pytest.raises(rigjax.PtoError, match=r"links of 'v' form a cycle through images \[0, 2\]"):
        rigjax.parse_project(text)


def test_missing_file_is_named(tmp_path):
    with pytest.raises(rigjax.PtoError, match=re.escape(str(tmp_path / "nope.pto")) + ".*cannot read"):
        rigjax.load_project(tmp_path / "nope.pto")


def test_ptgui_scripts_are_recognised():
    with pytest.raises(rigjax.PtoError, match="PTGui script"):
        rigjax.parse_project("# ptGui project file\np w100 h50 f2 v360\n")


# ---------------------------------------------------------------------------------------------
@pytest.mark.hugin
def test_hugin_accepts_written_projects(rich, tmp_path, hugin_tools):
    """A project rigjax wrote opens in Hugin: checkpto, autooptimiser and pano_trafo accept it."""
    p = synthetic.control_points_from_truth(synthetic.cube_rig(orientation_jitter_deg=2, seed=5), 300)
    out = tmp_path / "rig.pto"
    p.save(out)
    subprocess.run(["checkpto", str(out)], check=True, capture_output=True)
    subprocess.run(["autooptimiser", "-n", "-o", str(tmp_path / "opt.pto"), str(out)], check=True, capture_output=True)
    optimised = rigjax.load_project(tmp_path / "opt.pto")
    # Hugin honoured the v lines: image 0 (not listed) did not move, the lens was not optimised.
    written = rigjax.load_project(out)
    assert optimised.images[0] == written.images[0]
    assert [im.hfov for im in optimised.images] == [im.hfov for im in p.images]
    edited = rigjax.load_project(rich)
    edited = edited.replace(images=(edited.images[0].replace(yaw=3.25),) + edited.images[1:])
    edited.save(tmp_path / "edited.pto")
    # checkpto exits 2 here only because line control points leave image 2 unconnected.
    report = subprocess.run(["checkpto", str(tmp_path / "edited.pto")], capture_output=True, text=True).stdout
    assert "3 images\n1 lenses\n3 stacks\n5 control points" in report
    hugin = subprocess.run(
        ["pano_trafo", str(tmp_path / "edited.pto"), "0"],
        input="1999.5 1499.5\n",
        capture_output=True,
        text=True,
        check=True,
    ).stdout.split()
    ours, _ = rigjax.img_to_pano(edited.cameras().take(0), edited.canvas(), np.array([1999.5, 1499.5]))
    np.testing.assert_allclose(np.array(hugin, float), ours, atol=0.01)


def test_saved_project_is_an_ordinary_file(tmp_path):
    """Written atomically through a private temporary file, but readable as the umask allows."""
    import os

    old = os.umask(0o022)
    try:
        synthetic.cube_rig().save(tmp_path / "rig.pto")
    finally:
        os.umask(old)
    assert (tmp_path / "rig.pto").stat().st_mode & 0o777 == 0o644
    assert [p.name for p in tmp_path.iterdir()] == ["rig.pto"]  # no temporary file left


# Numbers at the edges of what a C parser holds (the reliability sweep's reproducers).
HEAD = "p f2 w360 h180 v360\ni w10 h10 f0 v50\n"
OUT_OF_RANGE = [
    (HEAD + "c n0 N0 x1 y1 X1 Y1 t99999999999999999999\n", r":3: token 't9999.*type 't' is out of range"),
    (HEAD + "c n0 N0 x1 y1 X1 Y1 t9223372036854775808\n", r"type 't' is out of range: '9223372036854775808'"),
    (HEAD + "c n0 N0 x1 y1 X1 Y1 t1e20\n", r"type 't' is out of range: '1e20'"),
    (HEAD + "c n99999999999999999999 N0 x1 y1 X1 Y1\n", r"'n' is out of range"),
    (HEAD.replace("w10", "w" + "1" * 5000), r":2: token 'w1111.*\(5001 characters\)': image width 'w' is out of range"),
    (HEAD.replace("w10", "w" + "9" * 400), r"image width 'w' is out of range"),
    (HEAD.replace("w10", "w1e300"), r"image width 'w' is out of range: '1e300'"),
    (HEAD + "v y" + "1" * 5000 + "\n", r":3: .*is out of range"),
    (HEAD + "i w10 h10 f0 v=" + "1" * 5000 + "\n", r":3: .*the link of 'v' is out of range"),
    (HEAD.replace("v50", "v0"), r":2: token 'v0': 'v' \(hfov\) must be positive"),
    (HEAD.replace("v50", "v-5"), r":2: token 'v-5': 'v' \(hfov\) must be positive"),
]


@pytest.mark.parametrize("text, message", OUT_OF_RANGE, ids=range(len(OUT_OF_RANGE)))
def test_numbers_out_of_range_are_refused_naming_the_line(text, message):
    with pytest.raises(rigjax.PtoError, match=message) as info:
        rigjax.parse_project(text)
    assert len(str(info.value)) < 200  # one readable line, however long the token


def test_a_long_malformed_number_is_refused_in_linear_time():
    import time

    # 40,000 digits then a letter: a backtracking pattern takes about half a minute (quadratic), a
    # linear one milliseconds. The bound is generous for slow machines.
    text = HEAD.replace("v50", "v" + "1" * 40_000 + "x")
    started = time.perf_counter()
    with pytest.raises(rigjax.PtoError, match=r":2: .*'v' \(hfov\) needs a number"):
        rigjax.parse_project(text)
    assert time.perf_counter() - started < 2.0


def test_a_lone_carriage_return_is_refused_alike_from_text_and_from_a_file(tmp_path):
    text = HEAD.replace("v50", "v50 X\r y45")
    with pytest.raises(rigjax.PtoError, match=r"<text>:2: a carriage return"):
        rigjax.parse_project(text)
    path = tmp_path / "cr.pto"
    path.write_bytes(text.encode())
    with pytest.raises(rigjax.PtoError, match=re.escape(str(path)) + r":2: a carriage return"):
        rigjax.load_project(path)
    # Windows line ends are line ends.
    path.write_bytes(HEAD.replace("\n", "\r\n").replace("v50", "v50 y45").encode())
    assert rigjax.load_project(path).images[0].yaw == 45.0


def test_a_project_that_cannot_be_read_back_is_not_written(tmp_path):
    project = rigjax.parse_project(HEAD + "i w10 h10 f0 v50\n")
    cameras = project.cameras(host=True)
    for field, value in (("yaw", np.nan), ("hfov", np.inf), ("hfov", 0.0)):
        bad = cameras._replace(**{field: np.asarray(getattr(cameras, field)).copy()})
        getattr(bad, field)[1] = value
        with pytest.raises(rigjax.RigjaxError, match=rf"image 1: camera field '{field}' is"):
            project.with_cameras(bad)
    image = project.images[0].replace(pitch=float("nan"))
    with pytest.raises(rigjax.RigjaxError, match="cannot write nan"):
        project.replace(images=(image, project.images[1])).save(tmp_path / "nan.pto")
    image = project.images[0].replace(filename='a"b.jpg')
    with pytest.raises(rigjax.RigjaxError, match="file name 'a\"b.jpg' cannot be written"):
        project.replace(images=(image, project.images[1])).to_text()
    assert not (tmp_path / "nan.pto").exists()


def test_every_letter_of_an_image_line_reaches_its_own_field():
    line = 'i w10 h20 f3 v1 a2 b3 c4 d5 e6 g7 t8 y9 p10 r11 TrX12 TrY13 TrZ14 Tpy15 Tpp16 n"x.jpg"'
    image = rigjax.parse_project("p f2 w360 h180 v360\n" + line + "\n").images[0]
    expected = dict(hfov=1, a=2, b=3, c=4, d=5, e=6, g=7, t=8, yaw=9, pitch=10, roll=11)
    expected |= dict(trans_x=12, trans_y=13, trans_z=14, trans_plane_yaw=15, trans_plane_pitch=16)
    assert image == rigjax.Image(width=10, height=20, projection=3, filename="x.jpg", **expected)


@pytest.mark.parametrize("enabled", [True, False])
def test_parsing_leaves_the_cyclic_collector_as_it_found_it(enabled):
    # The reader pauses the collector while it builds a project; a success or a refusal restores it.
    was = gc.isenabled()
    (gc.enable if enabled else gc.disable)()
    try:
        rigjax.parse_project("p f2 w360 h180 v360\ni w10 h10 f0 v50\n")
        assert gc.isenabled() is enabled
        with pytest.raises(rigjax.PtoError):
            rigjax.parse_project("p f2 w360 h180 v360\ni w0 h10 f0 v50\n")
        assert gc.isenabled() is enabled
    finally:
        (gc.enable if was else gc.disable)()


def test_long_link_chains_resolve_in_linear_time():
    import time

    # 3,000 images, each linking 'v' to the one before: every image follows the chain to image 0.
    # Following each chain anew took cubic time (about 40 s here); the bound is generous.
    n = 3000
    lines = ["p f2 w360 h180 v360", "i w10 h10 f0 v50"] + [f"i w10 h10 f0 v={k - 1}" for k in range(1, n)]
    started = time.perf_counter()
    project = rigjax.parse_project("\n".join(lines) + "\n")
    assert time.perf_counter() - started < 3.0
    assert project.images[-1].hfov == 50.0 and project.images[-1].links == {"v": 0}


def test_v_and_c_lines_between_other_lines_are_written_back_in_place():
    text = (
        HEAD
        + "i w10 h10 f0 v50 y90\n"
        + "v y1\n# a comment between v lines\nv p1\nv\n"
        + "c n0 N1 x1 y1 X2 Y2 t0\n#-hugin note\nc n0 N1 x3 y3 X4 Y4 t0\nunknown line\nc n0 N1 x5 y5 X6 Y6 t0\n"
        + "#hugin_optimizerMasterSwitch 0\n#hugin_optimizerPhotoMasterSwitch 0\n"
    )
    project = rigjax.parse_project(text)
    assert project.to_text() == text
    # Changed, they are written together at the first one's place; the other lines stay.
    changed = project.replace(variables=project.variables[:1]).to_text()
    assert "v y1\nv\n# a comment between v lines\nc n0" in changed


# ---------------------------------------------------------------------------------------------
# rigjax's own lines: camera centres and standard deviations.
RIGJAX_LINES = """\
#-rigjax centre 0 0 0 0.4
#-rigjax centre 1  0.346410161513775 0 -0.2
#-rigjax centre 2 -0.346410161513775 0 -0.2
#-rigjax sd 0 v0.17 y0.012 p0.01 r0.011
#-rigjax sd 1 v0.17 y0.012 p0.01 r0.011
#-rigjax sd 2 v0.17 y0.012 p0.01 r0.011
"""
LAST_IMAGE = 'u10 n"back.jpg"\n'


def test_centres_and_deviations_round_trip_byte_for_byte_and_edits_are_rendered():
    text = RICH.replace(LAST_IMAGE, LAST_IMAGE + RIGJAX_LINES)
    p = rigjax.parse_project(text)
    np.testing.assert_array_equal(p.centres[1], [0.346410161513775, 0.0, -0.2])
    assert p.deviations[2, 0] == 0.17 and np.isnan(p.deviations[2, 1:6]).all()
    assert p.to_text() == text  # double space and all
    centres = p.centres.copy()
    centres[0, 2] = 0.5
    edited = p.replace(centres=centres).to_text()
    assert "#-rigjax centre 0 0 0 0.5\n#-rigjax centre 1 0.346410161513775 0 -0.2\n" in edited
    assert edited.count("#-rigjax sd") == 3 and "#-rigjax sd 0 v0.17 y0.012 p0.01 r0.011\n" in edited
    np.testing.assert_array_equal(rigjax.parse_project(edited).centres, centres)
    assert "#-rigjax" not in p.replace(centres=None, deviations=None).to_text()
    added = rigjax.parse_project(RICH).replace(centres=centres).to_text()  # after the image lines
    assert LAST_IMAGE + "#-rigjax centre 0 0 0 0.5\n" in added


@pytest.mark.parametrize(
    "lines, message",
    [
        ("#-rigjax centre 5 0 0 1\n", r":12: token '5': '#-rigjax centre' refers to image 5, the project has 3"),
        ("#-rigjax centre 0 0 1\n", r":12: '#-rigjax centre' needs an image number and x y z, found 2 values"),
        ("#-rigjax centre 0 0 0 x\n", r":12: token 'x': a centre coordinate needs a number"),
        ("#-rigjax sd 0 q0.1\n", r":12: token 'q0.1': a standard deviation is one of v, a, b"),
        (
            "#-rigjax centre 0 0 0 1\n#-rigjax centre 1 0 0 1\n",
            r":12: '#-rigjax centre' lines give images \[0, 1\] but not image 2",
        ),
        ("#-rigjax centre 0 0 0 1\n" * 2, r":13: token '0': a second '#-rigjax centre' line for image 0"),
    ],
)
def test_bad_rigjax_lines_name_the_line(tmp_path, lines, message):
    path = tmp_path / "rich.pto"
    path.write_text(RICH.replace(LAST_IMAGE, LAST_IMAGE + lines))
    with pytest.raises(rigjax.PtoError, match=message):
        rigjax.load_project(path)


def test_centres_must_fit_the_images():
    p = rigjax.parse_project(RICH)
    with pytest.raises(rigjax.RigjaxError, match=r"centres has shape \(2, 3\), expected \(3, 3\)"):
        p.replace(centres=np.zeros((2, 3)))
