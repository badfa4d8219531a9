"""learnstitch.video.turns (``learnstitch turns``): the camera's turn in every frame of a clip,
against the poses a synthetic clip of a walking, turning dual-fisheye camera was rendered with;
and learnstitch.video.stabilise (``--stabilise``), which levels and steadies the stitch by them."""

import av
import numpy as np
import pytest

import rigjax
from learnstitch.cli import main
from learnstitch.data.sequence import Motion, draw_sequence
from learnstitch.video import video_panoramas
from learnstitch.video.colour import Colour, from_rgb, yuv_planes
from learnstitch.video.stabilise import Steady, output_turns, smoothed_heading
from learnstitch.video.turns import Turns, clip_turns, measure_turns, read_turns

SIZE, FRAMES, FPS = 320, 8, 10
# 6 degrees of turn and 14 cm of walk a frame, up to 4 degrees of wobble in pitch and roll.
MOTION = Motion(speed=1.4, yaw_rate=60.0, wobble_deg=4.0, fps=FPS, duration=1.0)
TOLERANCE_DEG = 0.5  # a pixel of these 320-pixel, 190-degree lenses is 0.6 degrees
BT709_LIMITED = Colour(1, 1, 1, 1)  # matrix, range, primaries, transfer (FFmpeg's codes)


def _angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The angle between rotations ``a`` and ``b`` (..., 3, 3), degrees."""
    cos = (np.trace(np.swapaxes(a, -1, -2) @ b, axis1=-2, axis2=-1) - 1) / 2
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


@pytest.fixture(scope="module")
def clip(tmp_path_factory):
    """The clip (side by side, H.264), its rig's project and the true turn of each frame."""
    folder = tmp_path_factory.mktemp("turns")
    truth = draw_sequence("dual", 3, SIZE, MOTION)
    frames = list(truth.frames(FRAMES, pano_width=64))
    first = frames[0].pose.world_from_rig
    true_turns = np.stack([first.T @ f.pose.world_from_rig for f in frames])
    rig = folder / "rig.pto"
    truth.project().save(rig)
    path = folder / "walk.mp4"
    with av.open(str(path), "w", format="mp4") as out:
        stream = out.add_stream("libx264", rate=FPS, options={"crf": "12", "preset": "veryfast"})
        stream.width, stream.height, stream.pix_fmt = 2 * SIZE, SIZE, "yuv420p"
        for k, frame in enumerate(frames):
            picture = av.VideoFrame.from_ndarray(frame.side_by_side, format="rgb24")
            picture.pts = k
            out.mux(stream.encode(picture))
        out.mux(stream.encode(None))
    return rig, path, [f.images for f in frames], true_turns


def test_the_turns_of_a_walking_turning_camera_are_the_poses_it_was_rendered_with(clip):
    """Every frame within half a pixel's angle of its true turn (up to 42 degrees from the first
    frame), through key frames that move on as the view does."""
    rig, _, images, true_turns = clip
    turns = measure_turns(rigjax.load_project(rig), list(enumerate(images)), FPS)
    assert _angle_deg(true_turns[-1], np.eye(3)) > 40.0
    errors = _angle_deg(turns.rotations, true_turns)
    assert errors.max() < TOLERANCE_DEG, errors
    assert turns.keys[0] and turns.keys.sum() >= 2 and not turns.lost.any()
    assert (turns.inliers[1:] >= 25).all() and turns.inliers[0] == 0
    np.testing.assert_allclose(turns.times, np.arange(FRAMES) / FPS)


def test_learnstitch_turns_writes_the_clips_turns_beside_the_pto(clip, capsys):
    rig, path, _, true_turns = clip
    assert main(["turns", "--rig", str(rig), "--video", str(path)]) == 0
    written = rig.with_name("walk.turns.csv")
    assert str(written) in capsys.readouterr().out
    turns = read_turns(written)
    np.testing.assert_array_equal(turns.frames, np.arange(FRAMES))
    assert _angle_deg(turns.rotations, true_turns).max() < TOLERANCE_DEG
    # From a later frame on: that frame is the first, its turn the identity.
    later = rig.with_name("later.csv")
    assert main(["turns", "--rig", str(rig), "--video", str(path), "--time", "0.3", "-o", str(later)]) == 0
    turns = read_turns(later)
    np.testing.assert_array_equal(turns.frames, np.arange(3, FRAMES))
    expected = np.swapaxes(true_turns[3], -1, -2) @ true_turns[3:]
    assert _angle_deg(turns.rotations, expected).max() < TOLERANCE_DEG


def test_the_csv_reads_back_and_a_damaged_line_is_named(tmp_path):
    rng = np.random.default_rng(0)
    ypr = np.column_stack([rng.uniform(-180, 180, 5), rng.uniform(-80, 80, 5), rng.uniform(-180, 180, 5)])
    rotations = np.asarray(rigjax.world_from_cam(*ypr.T), np.float64)
    turns = Turns(
        np.arange(5),
        np.arange(5) / 30.0,
        rotations,
        np.array([0, 40, 41, 42, 43]),
        np.eye(5, dtype=bool)[0],
        np.zeros(5, bool),
    )
    path = turns.write(tmp_path / "t.csv")
    back = read_turns(path)
    assert _angle_deg(back.rotations, rotations).max() < 1e-5  # six decimals of a degree
    np.testing.assert_array_equal(back.inliers, turns.inliers)
    np.testing.assert_array_equal(back.keys, turns.keys)
    lines = path.read_text().splitlines()
    path.write_text("\n".join([*lines[:2], "2,0.066667,1.0,2.0", *lines[3:]]) + "\n")
    with pytest.raises(rigjax.RigjaxError, match=r"t\.csv, line 3: expected 8 values"):
        read_turns(path)
    path.write_text("frame,time\n")
    with pytest.raises(rigjax.RigjaxError, match=r"t\.csv, line 1: expected the header"):
        read_turns(path)


def _row_profile(pano: np.ndarray) -> np.ndarray:
    """Each row's mean grey: unchanged by a turn about the vertical (a shift along the rows), moved
    by any pitch or roll."""
    return pano.astype(np.float64).mean(axis=(1, 2))


def test_a_yaw_of_whole_pixels_is_a_shift_of_the_columns():
    """The steadied panorama of a pure yaw of 7 columns' angle is the panorama shifted 7 columns
    (bicubic at whole pixels is exact): the maps' convention and sign against np.roll."""
    rng = np.random.default_rng(2)
    pano = rng.integers(0, 256, (32, 64, 3), dtype=np.uint8)
    yaw = np.asarray(rigjax.world_from_cam(7 * 360.0 / 64, 0.0, 0.0), np.float64)
    steady = Steady({5: yaw}, colour=None)
    np.testing.assert_array_equal(steady(5, pano), np.roll(pano, -7, axis=1))
    with pytest.raises(rigjax.RigjaxError, match="no turn for frame 6"):
        steady(6, pano)
    # The same on a frame's 4:2:0 planes, 68 x 34 (chroma of an odd 17 rows): its luma shifted alike.
    frame = from_rgb(rng.integers(0, 256, (34, 68, 3), dtype=np.uint8), BT709_LIMITED)
    yaw = np.asarray(rigjax.world_from_cam(7 * 360.0 / 68, 0.0, 0.0), np.float64)
    turned = Steady({0: yaw}, BT709_LIMITED)(0, frame)
    np.testing.assert_array_equal(yuv_planes(turned)[0], np.roll(yuv_planes(frame)[0], -7, axis=1))
    assert (turned.width, turned.height, int(turned.colorspace)) == (68, 34, 1)


def test_a_sample_near_a_pole_reads_beyond_that_pole_not_the_other():
    """A grey canvas with a white bottom row, turned a tenth of a degree in pitch: its top rows stay
    grey (a sample wrapping from top to bottom would pull them towards white)."""
    pano = np.full((32, 64, 3), 100, np.uint8)
    pano[-1] = 250
    pitch = np.asarray(rigjax.world_from_cam(0.0, 0.1, 0.0), np.float64)
    turned = Steady({0: pitch}, colour=None)(0, pano)
    assert np.abs(turned[:3].astype(int) - 100).max() <= 1


def test_steadied_panoramas_keep_the_first_frames_horizon_and_a_smoothed_heading():
    """A camera turning 6 degrees a frame on the spot with 8 degrees of wobble in pitch and roll,
    stabilised through its true turns: every frame's panorama is the first frame's turned about
    the vertical alone (each row's mean as the first frame's), where the frames as stitched tilt."""
    truth = draw_sequence("dual", 3, 48, Motion(speed=0.0, yaw_rate=60.0, wobble_deg=8.0, fps=FPS, duration=1.0))
    frames = list(truth.frames(FRAMES, pano_width=256))
    first = frames[0].pose.world_from_rig
    rotations = np.stack([first.T @ f.pose.world_from_rig for f in frames])
    turns = Turns(
        np.arange(FRAMES), np.arange(FRAMES) / FPS, rotations, *(np.zeros(FRAMES, t) for t in (int, bool, bool))
    )
    steady = Steady(output_turns(turns, FPS), colour=None)
    reference = _row_profile(frames[0].pano)
    tilted = [np.abs(_row_profile(f.pano) - reference).mean() for f in frames[1:]]
    level = [np.abs(_row_profile(steady(f.index, f.pano)) - reference).mean() for f in frames[1:]]
    # What is left is the first frame's own tilt (0.7 degrees in pitch and in roll as drawn), about
    # which the camera's turn is not vertical.
    assert max(tilted) > 3.0 and max(level) < 0.25 * max(tilted), (tilted, level)
    # A steady pan is kept: the heading is the turn's, smoothed (a 1 s Gaussian of a straight line
    # is the line, but for the held ends).
    heading = smoothed_heading(turns, FPS, sigma_s=0.1)
    np.testing.assert_allclose(heading[3:-3], 60.0 * np.arange(3, FRAMES - 3) / FPS, atol=0.5)


def test_the_stitch_stabilises_a_clip_with_its_measured_turns_and_refuses_turns_that_miss_frames(clip, tmp_path):
    rig, path, _, _ = clip
    options = {"mode": "template", "width": 128, "template_cache": False}
    plain = dict(video_panoramas(rig, [path], **options))
    measured = clip_turns(rig, [path]).turns
    steadied = dict(video_panoramas(rig, [path], stabilise=True, **options))
    steady = Steady(output_turns(measured, FPS), colour=None)
    for t in (2, 7):  # the stitch's own frames, turned by the turns `learnstitch turns` measures
        assert np.abs(steadied[t].astype(int) - steady(t, plain[t]).astype(int)).mean() < 1.0
    out = tmp_path / "steady.mp4"  # the command: its encoder thread turns the frames as the generator does
    args = ["stitch", "--rig", str(rig), "--video", str(path), "--mode", "template", "--width", "128", "--quiet"]
    assert main([*args, "-o", str(out), "--stabilise", "--stabilise-seconds", "1"]) == 0
    with av.open(str(out)) as container:
        written = [f.to_ndarray(format="rgb24") for f in container.decode(video=0)]
    assert len(written) == FRAMES
    # H.264 at crf 18 of a 128-pixel frame, turned in its 4:2:0 planes: a few grey levels from the
    # generator's frame turned in RGB, where the frame as stitched is many more.
    off, unturned = (np.abs(written[7].astype(int) - p[7].astype(int)).mean() for p in (steadied, plain))
    assert off < 5.0 and off < 0.3 * unturned, (off, unturned)
    short = measured._replace(frames=measured.frames[:5], times=measured.times[:5], rotations=measured.rotations[:5])
    csv = short._replace(inliers=measured.inliers[:5], keys=measured.keys[:5], lost=measured.lost[:5]).write(
        tmp_path / "t.csv"
    )
    code = main(
        [
            "stitch",
            "--rig",
            str(rig),
            "--video",
            str(path),
            "-o",
            str(tmp_path / "p.mp4"),
            "--mode",
            "template",
            "--stabilise",
            str(csv),
        ]
    )
    assert code == 2 and not (tmp_path / "p.mp4").exists()
