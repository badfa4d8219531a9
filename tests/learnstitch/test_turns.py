"""learnstitch.video.turns (``learnstitch turns``): the camera's turn in every frame of a clip,
against the poses a synthetic clip of a walking, turning dual-fisheye camera was rendered with."""

import av
import numpy as np
import pytest

import rigjax
from learnstitch.cli import main
from learnstitch.data.sequence import Motion, draw_sequence
from learnstitch.video.turns import Turns, measure_turns, read_turns

SIZE, FRAMES, FPS = 320, 8, 10
# 6 degrees of turn and 14 cm of walk a frame, up to 4 degrees of wobble in pitch and roll.
MOTION = Motion(speed=1.4, yaw_rate=60.0, wobble_deg=4.0, fps=FPS, duration=1.0)
TOLERANCE_DEG = 0.5  # a pixel of these 320-pixel, 190-degree lenses is 0.6 degrees


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
    with pytest.raises(rigjax.RigjaxError, match=r"t\.csv, line 3: expected 7 values"):
        read_turns(path)
    path.write_text("frame,time\n")
    with pytest.raises(rigjax.RigjaxError, match=r"t\.csv, line 1: expected the header"):
        read_turns(path)
