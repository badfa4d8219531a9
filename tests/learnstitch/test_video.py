"""The 360-video path (learnstitch.video): a synthetic dual-fisheye clip stitched as a user would.

Frames against the still stitch of the same images, the template remap against the rotation-only
render, the camera's turn found by the temporal filter against the turn the clip was rendered
with, offsets against the shift the clips were cut with, the file against what was asked (frame
count, rate, audio packets, spherical metadata read by the tests' own box reader), a run killed
with SIGKILL and resumed against an uninterrupted one, and each bad input's one line.
"""

from __future__ import annotations

import dataclasses
import math
import os
import random
import re
import signal
import subprocess
import sys
import threading
import time
from fractions import Fraction
from pathlib import Path

import av
import cv2
import mp4_boxes  # tests/learnstitch/mp4_boxes.py, the independent reader
import numpy as np
import pytest
import torch

import rigjax
from learnstitch.cli import main
from learnstitch.data.dual import draw_dual, render_dual_frames
from learnstitch.fullres.config import RenderConfig
from learnstitch.fullres.depth import Depth, pano_rays
from learnstitch.fullres.rig import load_rig
from learnstitch.fullres.stitcher import Frame, GivenDepth, Stitcher
from learnstitch.inference import stitch_project
from learnstitch.video import Encoding, VideoStitch, pipeline, stitch_video, video_panoramas
from learnstitch.video.source import Footage, layout, split
from learnstitch.video.sync import audio_offsets
from learnstitch.video.template import _BAND_COLUMNS, Layers, _remap
from learnstitch.video.temporal import DEPTH_SIGMA, STRENGTH, carry, frame_turn
from rigjax.camera.photometry import PHOTOMETRIC_LETTERS
from rigjax.pto.records import IMAGE_DEFAULTS, IMAGE_FIELDS

SIZE, FRAMES, RATE, TURN_DEG, WIDTH = 128, 12, 30, 3.0, 256
AUDIO_RATE = 48000
SPF = AUDIO_RATE // RATE  # audio samples a frame
SMALL = RenderConfig(working_width=128, depth_planes=12)  # a small working canvas: the tests' clips are small


def write_clip(path, frames, rate=RATE, audio=None, faststart=False):
    """``frames`` (RGB uint8) as an H.264 MP4 (lossless in YUV), with mono float ``audio`` as AAC."""
    options = {"movflags": "+faststart"} if faststart else {}
    with av.open(str(path), "w", format="mp4", options=options) as out:
        video = out.add_stream("libx264", rate=rate, options={"crf": "0", "preset": "ultrafast"})
        video.height, video.width = frames[0].shape[:2]
        video.pix_fmt = "yuv420p"
        if audio is not None:
            sound = out.add_stream("aac", rate=AUDIO_RATE, layout="mono")
        for i, rgb in enumerate(frames):
            frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(rgb), format="rgb24")
            frame.pts = i
            out.mux(video.encode(frame))
        out.mux(video.encode(None))
        if audio is not None:
            for start in range(0, len(audio), 1024):
                chunk = av.AudioFrame.from_ndarray(audio[None, start : start + 1024], format="fltp", layout="mono")
                chunk.sample_rate, chunk.pts = AUDIO_RATE, start
                out.mux(sound.encode(chunk))
            out.mux(sound.encode(None))
    return path


def decode_rgb(path):
    with av.open(str(path)) as container:
        return [frame.to_ndarray(format="rgb24") for frame in container.decode(video=0)]


def audio_packets(path, since=-1.0, until=99.0) -> list[bytes]:
    """The audio packets of ``path`` presented ``since .. until`` seconds."""
    with av.open(str(path)) as container:
        stream = container.streams.audio[0]
        return [
            bytes(p)
            for p in container.demux(stream)
            if p.size and since - 1e-9 <= float(p.pts * stream.time_base) < until - 1e-9
        ]


def noise(samples, seed=1):
    return np.random.default_rng(seed).normal(0.0, 0.2, samples).astype(np.float32)


@pytest.fixture(scope="module")
def dual(tmp_path_factory):
    """A dual-fisheye camera's side-by-side clip (turning ``TURN_DEG`` a frame, with audio) and its rig."""
    folder = tmp_path_factory.mktemp("video")
    truth = draw_dual(3, SIZE)
    frames = render_dual_frames(3, truth, FRAMES, turn_deg=TURN_DEG)
    rig = folder / "rig.pto"
    truth.project(("left.png", "right.png"), panorama_width=WIDTH).save(rig)
    clip = write_clip(folder / "clip.mp4", frames, audio=noise(FRAMES * SPF))
    return folder, rig, clip


def test_a_side_by_side_frame_is_cut_into_the_pto_images_left_to_right(dual, tmp_path):
    frame = np.concatenate([np.full((4, 3, 3), k, np.uint8) for k in range(3)], axis=1)
    assert [int(part[0, 0, 0]) for part in split(frame, 3)] == [0, 1, 2]
    _, rig, clip = dual
    found = layout([clip], [(SIZE, SIZE)] * 2, None, "rig.pto")
    assert found.parts == 2 and found.rate == RATE and found.infos[0].frames == FRAMES
    # Hugin's form: every i line the whole frame, each camera's image the whole frame.
    whole = layout([clip], [(2 * SIZE, SIZE)] * 2, None, "rig.pto")
    assert (whole.parts, whole.shared) == (1, 2) and found.shared == 0
    with pytest.raises(ValueError, match=r"256 x 128 frames do not cut into the 3 images of rig\.pto"):
        layout([clip], [(SIZE, SIZE)] * 3, None, "rig.pto")


@pytest.mark.parametrize("count", [None, 0, 2])
def test_footage_peeked_goes_on_as_footage_read_from_its_start(dual, count):
    # The preparation decodes the first frame and the decoder runs ahead while the stitch is set
    # up; the stitch then reads on from it, with a count shorter than what was decoded ahead.
    _, rig, clip = dual
    found = layout([clip], [(SIZE, SIZE)] * 2, None, "rig.pto")
    fresh = [(t, frames[0].to_ndarray()) for t, frames in Footage(found, 1, count)]
    assert [t for t, _ in fresh] == list(range(1, 1 + (FRAMES - 1 if count is None else count)))
    peeked = Footage(found, 1, None)
    t, frames = peeked.peek()
    if fresh:
        np.testing.assert_array_equal(frames[0].to_ndarray(), fresh[0][1])
    assert t == 1 and peeked.peek()[1] is frames  # peeking again gives the same frame
    peeked.count = count
    read = [(t, frames[0].to_ndarray()) for t, frames in peeked]
    assert [t for t, _ in read] == [t for t, _ in fresh]
    for (_, a), (_, b) in zip(read, fresh):
        np.testing.assert_array_equal(a, b)


def test_a_decoder_run_on_past_the_count_has_not_stopped_before_it(dual):
    _, rig, clip = dual
    found = layout([clip], [(SIZE, SIZE)] * 2, None, "rig.pto")
    footage = Footage(found, FRAMES - 3, None)
    footage.peek()
    deadline = time.monotonic() + 30
    while footage.stopped is None and time.monotonic() < deadline:  # no count yet: the decoder reaches the end
        time.sleep(0.01)
    assert footage.stopped is not None and footage.stopped.frame == FRAMES
    footage.count = 2
    assert [t for t, _ in footage] == [FRAMES - 3, FRAMES - 2]
    assert footage.stopped is None  # the two frames asked for were there


def test_a_decoder_left_running_is_stopped_where_no_footage_reads_it(dual, monkeypatch):
    _, rig, clip = dual

    def decoders():
        return sum(thread.name == "decode" and thread.is_alive() for thread in threading.enumerate())

    before = decoders()
    VideoStitch.prepare(rig, [clip], width=WIDTH, mode="template")
    assert decoders() == before  # not kept
    stitch = VideoStitch.prepare(rig, [clip], width=WIDTH, mode="template", keep_decoding=True)
    assert decoders() == before + 1
    assert [t for t, _ in stitch.footage(3, 2)] == [3, 4]  # another start: a footage of its own
    assert decoders() == before
    stitch = VideoStitch.prepare(rig, [clip], width=WIDTH, mode="template", keep_decoding=True)
    stitch.close()
    assert decoders() == before

    def fails(*args, **kwargs):
        raise RuntimeError("the maps could not be made")

    monkeypatch.setattr(pipeline, "prepare_template", fails)  # the set-up fails after the first frame
    with pytest.raises(RuntimeError, match="maps"):
        VideoStitch.prepare(rig, [clip], width=WIDTH, mode="template", keep_decoding=True)
    assert decoders() == before


def test_a_frame_of_the_video_is_the_still_stitch_of_that_frame(dual):
    _, rig, clip = dual
    decoded = decode_rgb(clip)
    options = {"width": WIDTH, "model": "sweep", "config": SMALL, "duration": 6 / RATE}
    unfiltered = dict(video_panoramas(rig, [clip], temporal=False, **options))
    filtered = dict(video_panoramas(rig, [clip], **options))
    assert sorted(unfiltered) == list(range(6))
    for k in (0, 5):
        still = stitch_project(rig, WIDTH, "sweep", images=split(decoded[k], 2), config=SMALL).stitched.pano
        np.testing.assert_array_equal(unfiltered[k], still)
    np.testing.assert_array_equal(filtered[0], unfiltered[0])  # nothing before the first frame to filter with


def test_the_written_frames_are_the_panoramas_one_by_one(dual, tmp_path):
    """stitch_video renders a frame while it measures the next: its frames (losslessly encoded) are
    video_panoramas' (one after another), key frames and held colour correction included. Segments
    of 2 frames: the filter is reset and primed on every frame before each (fewer than 4) while the
    previous frame renders, and must come out as if it ran unbroken."""
    _, rig, clip = dual
    options = {"width": WIDTH, "model": "sweep", "config": SMALL, "duration": 5 / RATE, "depth_every": 2}
    out = tmp_path / "pano.mp4"
    stitch_video(rig, [clip], out, encoding=Encoding(crf=0), audio=None, segment_frames=2, **options)
    with av.open(str(out)) as container:
        written = [frame.to_ndarray() for frame in container.decode(video=0)]
    expected = [
        av.VideoFrame.from_ndarray(pano, format="rgb24").reformat(format="yuv420p").to_ndarray()
        for _, pano in video_panoramas(rig, [clip], **options)
    ]
    assert len(written) == len(expected) == 5
    for k, (got, want) in enumerate(zip(written, expected)):
        np.testing.assert_array_equal(got, want, err_msg=f"frame {k}")


def test_a_canvas_is_carried_through_a_turn_as_its_directions_turn():
    # f(d) = d_x + 2 d_y + 3 d_z on the previous frame's canvas, carried through prev_from_cur R,
    # is f(R d) at the current frame's ray d (away from the poles, where bilinear reads are exact enough)
    width, height = 512, 256
    rays = pano_rays(width, height).double()
    weights = torch.tensor([1.0, 2.0, 3.0], dtype=torch.float64)
    angle = math.radians(4.0)
    turn = np.array([[math.cos(angle), 0, math.sin(angle)], [0, 1, 0], [-math.sin(angle), 0, math.cos(angle)]])
    tilt = np.array([[1, 0, 0], [0, math.cos(0.03), -math.sin(0.03)], [0, math.sin(0.03), math.cos(0.03)]])
    prev_from_cur = turn @ tilt
    carried = carry((rays @ weights).float()[None], prev_from_cur)[0]
    expected = (rays @ torch.from_numpy(prev_from_cur).T) @ weights
    middle = slice(height // 8, height - height // 8)
    assert (carried - expected)[middle].abs().max() < 0.02  # a pixel's slope of f is 2 pi / 512 * 3.7


def _rotation_angle_deg(rotation):
    return math.degrees(math.acos(np.clip((np.trace(rotation) - 1.0) / 2.0, -1.0, 1.0)))


@pytest.mark.parametrize("turn_deg, gain", [(0.5, 1.0), (12.0, 1.0), (4.0, 1.4)])
def test_the_turn_between_two_canvases_is_found_to_hundredths_of_a_degree(turn_deg, gain):
    # A textured canvas (blurred noise) turned by a known rotation through carry(), brightened by
    # `gain` (an exposure step between frames): frame_turn finds the rotation far within a pixel
    # (512 around: 0.7 degrees a pixel)
    rng = np.random.default_rng(7)
    texture = cv2.GaussianBlur(rng.uniform(0, 255, (256, 512)).astype(np.float32), (0, 0), 2.0)
    previous = cv2.normalize(texture, None, 20, 235, cv2.NORM_MINMAX).astype(np.uint8)
    yaw, tilt = math.radians(turn_deg), math.radians(0.3 * turn_deg)
    prev_from_cur = np.array(
        [[math.cos(yaw), 0, math.sin(yaw)], [0, 1, 0], [-math.sin(yaw), 0, math.cos(yaw)]]
    ) @ np.array([[1, 0, 0], [0, math.cos(tilt), -math.sin(tilt)], [0, math.sin(tilt), math.cos(tilt)]])
    current = carry(torch.from_numpy(previous).float()[None], prev_from_cur)[0].numpy()
    current = np.clip(current * gain + 0.5, 0, 255).astype(np.uint8)
    found = frame_turn(previous, current)
    assert found is not None
    assert _rotation_angle_deg(found.T @ prev_from_cur) < 0.02


def test_no_turn_is_found_between_unrelated_canvases():
    rng = np.random.default_rng(3)
    blank = np.full((256, 512), 90, np.uint8)
    assert frame_turn(blank, blank) is None  # nothing to track
    noise = [rng.integers(0, 256, (256, 512)).astype(np.uint8) for _ in range(2)]
    assert frame_turn(*noise) is None


def test_the_filter_finds_the_turn_the_clip_was_rendered_with(dual):
    _, rig, clip = dual
    stitch = VideoStitch.prepare(rig, [clip], width=WIDTH, model="sweep", config=RenderConfig(128, depth_planes=4))
    for _, frames in Footage(stitch.layout, 0, 6):
        stitch.prime(frames)  # the filter alone, no render
    turns = stitch.temporal.turns
    assert turns[0] is None and all(t is not None for t in turns[1:])
    for turn in turns[1:]:
        axis = np.array([turn[2, 1] - turn[1, 2], turn[0, 2] - turn[2, 0], turn[1, 0] - turn[0, 1]])
        assert _rotation_angle_deg(turn) == pytest.approx(TURN_DEG, abs=0.25)
        assert abs(axis[1]) / np.linalg.norm(axis) > 0.99  # about the vertical (the rig's y, camera 0's frame)


class _StillCanvas:
    """A grey canvas that never changes: what the filter sees of a still scene."""

    seen = np.ones((64, 128), bool)
    mask = seen.astype(np.uint8)

    def __call__(self, pixels):
        return np.full(self.seen.shape, 100, np.uint8)


def test_the_filter_smooths_jitter_and_lets_a_change_of_depth_through(dual, monkeypatch):
    """A still camera (the turn found: none) and an unchanging grey canvas: the filtered depth is
    q' + a (q_prev - q'), a = strength exp(-(q' - q_prev)^2 / (2 s_q^2)). A jitter well under s_q is
    mostly smoothed away; a step of many s_q (a near object arriving) is taken at once."""
    _, rig, clip = dual
    stitch = VideoStitch.prepare(rig, [clip], width=WIDTH, model="sweep", config=SMALL)
    filtered = stitch.temporal
    first = torch.full((32, 64), 0.5)
    second = first.clone()
    second[:, :32] += 0.01  # jitter
    second[:, 32:] += 0.6  # a near object
    estimates = iter([first, second])
    filtered.inner = lambda frame, config: Depth(next(estimates))
    filtered.canvas = _StillCanvas()
    monkeypatch.setattr("learnstitch.video.temporal.frame_turn", lambda previous, current, **_: np.eye(3))
    frame = Frame([torch.zeros(3, 8, 8)], None, [np.zeros((8, 8, 3), np.uint8)])
    filtered(frame, SMALL)
    out = filtered(frame, SMALL).working
    for step, columns in ((0.01, slice(0, 32)), (0.6, slice(32, 64))):
        a = STRENGTH * math.exp(-0.5 * (step / DEPTH_SIGMA) ** 2)
        expected = torch.full((32, 32), 0.5 + step * (1.0 - a))
        torch.testing.assert_close(out[:, columns], expected, atol=1e-6, rtol=0)
    assert (out[:, :32] - 0.5).abs().max() < 0.003 and (out[:, 32:] - 1.1).abs().max() < 1e-6


def test_the_refined_depth_is_filtered_the_same_way_and_carried_between_key_frames(dual, monkeypatch):
    """The stitcher's refined depth (another canvas than the working depth's) goes through the same
    rule, q' + a (q_prev - q'); a frame between key frames gets the previous refined depth carried
    through its turn (here none), with its confidence, so that the stitcher does not refine it."""
    _, rig, clip = dual
    stitch = VideoStitch.prepare(rig, [clip], width=WIDTH, model="sweep", config=SMALL)
    filtered = stitch.temporal
    assert stitch.stitcher.depth_filter == filtered.refined
    filtered.inner = lambda frame, config: Depth(torch.full((32, 64), 0.5))
    filtered.canvas = _StillCanvas()
    monkeypatch.setattr("learnstitch.video.temporal.frame_turn", lambda previous, current, **_: np.eye(3))
    frame = Frame([torch.zeros(3, 8, 8)], None, [np.zeros((8, 8, 3), np.uint8)])
    confidence = torch.full((64, 128), 0.7)
    refined = [torch.full((64, 128), 0.4), torch.full((64, 128), 0.4)]
    refined[1][:, :64] += 0.01  # jitter
    refined[1][:, 64:] += 0.6  # a near object
    outs = []
    for depth in refined:
        filtered(frame, SMALL)
        outs.append(filtered.refined(Depth(depth, confidence=confidence)).working)
    torch.testing.assert_close(outs[0], refined[0])  # nothing before the first frame
    for step, columns in ((0.01, slice(0, 64)), (0.6, slice(64, 128))):
        a = STRENGTH * math.exp(-0.5 * (step / DEPTH_SIGMA) ** 2)
        torch.testing.assert_close(outs[1][:, columns], torch.full((64, 64), 0.4 + step * (1.0 - a)), atol=1e-6, rtol=0)
    filtered.estimate = False  # between key frames
    carried = filtered(frame, SMALL)
    assert carried.working.shape == (64, 128) and carried.confidence is not None
    torch.testing.assert_close(carried.working[8:-8], outs[1][8:-8], atol=1e-5, rtol=0)  # turned by nothing
    # Turned by a quarter turn about the vertical, the depth, its confidence and a network's blend
    # shares all turn with the camera (a column roll of a quarter of the canvas).
    shares = torch.rand(2, 64, 128, generator=torch.Generator().manual_seed(0))
    filtered._refined = filtered._refined._replace(confidence=torch.rand(64, 128), shares=shares)
    before = filtered._refined
    quarter = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])  # prev_from_cur
    monkeypatch.setattr("learnstitch.video.temporal.frame_turn", lambda previous, current, **_: quarter)
    turned = filtered(frame, SMALL)
    for got, was in (
        (turned.working, before.working),
        (turned.confidence, before.confidence),
        *zip(turned.shares, shares),
    ):
        torch.testing.assert_close(got[8:-8], torch.roll(was, -32, dims=-1)[8:-8], atol=1e-4, rtol=0)


@pytest.mark.parametrize("width", [WIDTH, 264])  # 264: PyAV pads the planes' rows, the remap goes beside
def test_the_template_is_the_rotation_only_stitch(dual, width):
    _, rig, clip = dual
    stitch = VideoStitch.prepare(rig, [clip], width=width, mode="template")
    frames = next(iter(Footage(stitch.layout, 4, 1)))[1]
    planes = stitch(frames).to_ndarray()  # yuv420p: the Y plane, then U and V, as (3 H / 2, W)
    images = split(frames[0].to_ndarray(format="rgb24"), 2)
    # The remaps alone: the template corrects no colour, the .pto's stated photometry included
    flat = Stitcher.prepare(load_rig(rig, images)._replace(undo=None), width, RenderConfig(photometry="none"))
    still = flat(images, depth=GivenDepth(working=torch.zeros(256, 512)))
    # The still through FFmpeg's RGB to YUV conversion: the round trip from the decoded YUV is off
    # by a constant level (its rounding); the remaps must agree up to that
    expected = av.VideoFrame.from_ndarray(still.pano, format="rgb24").reformat(format="yuv420p").to_ndarray()
    height = width // 2
    luma = planes[:height]
    difference = (luma.astype(float) - expected[:height])[still.covered]
    offset = np.median(difference)
    assert abs(offset) <= 1.0
    assert np.abs(difference - offset).mean() < 0.3 and np.percentile(np.abs(difference - offset), 99) < 4.0
    assert np.all(luma[~still.covered] == 16)  # black where no camera sees
    # Chroma: U and V, each (H / 2, W / 2), laid out as H / 4 rows of W after the luma
    chroma = planes[height:].reshape(2, height // 2, width // 2).astype(float)
    wanted = expected[height:].reshape(2, height // 2, width // 2)
    inside = still.covered[::2, ::2] & still.covered[1::2, ::2] & still.covered[::2, 1::2] & still.covered[1::2, 1::2]
    for got, want in zip(chroma, wanted):
        offset = np.median((got - want)[inside])
        assert abs(offset) <= 1.0 and np.abs(got - want - offset)[inside].mean() < 0.6


def test_the_template_band_is_the_feather_weighted_mean_of_each_cameras_read():
    # Two cameras' maps over a small canvas, the second fading in across a band of columns: the
    # template's remap against each camera's map remapped whole and blended per pixel in float.
    rng = np.random.default_rng(5)
    plane = rng.integers(0, 256, (60, 90), np.uint8)
    ys, xs = np.mgrid[0:24, 0:36].astype(np.float32)
    cameras = [(xs * 1.3 + 2.2, ys * 1.2 + 3.4), (xs * 1.1 + 0.3 * ys + 40.7, ys * 1.4 + 1.1)]
    second = np.clip((xs - 10.0) / 16.0, 0.0, 1.0)
    shares = np.stack([1.0 - second, second]).astype(np.float32)
    best = shares.argmax(0)
    primary = tuple(np.where(best == 0, cameras[0][i], cameras[1][i]) for i in (0, 1))
    band = np.flatnonzero((shares > 0).all(0))
    padding = (0, _BAND_COLUMNS - band.size)
    other = 1 - best.ravel()[band]
    maps = [tuple(np.pad(np.choose(other, [c[i].ravel()[band] for c in cameras]), padding)[None] for i in (0, 1))]
    weights = [
        np.pad(np.choose(k, [s.ravel()[band] for s in shares]), padding)[None] for k in (best.ravel()[band], other)
    ]
    layers = Layers(primary, band, maps, weights)
    out = np.empty((24, 36), np.uint8)
    _remap(plane, layers, 16, out)
    reads = [cv2.remap(plane, *c, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=16) for c in cameras]
    blended = (shares * np.stack(reads).astype(np.float32)).sum(0)
    inside = np.zeros(out.size, bool)
    inside[band] = True
    inside = inside.reshape(out.shape)
    assert 0 < inside.sum() < out.size
    assert np.array_equal(out[~inside], np.choose(best, reads)[~inside])  # one camera: its read as it is
    assert np.abs(out[inside] - blended[inside]).max() <= 0.5 + 1e-3  # the blend: its mean, rounded


def hugin_form(project: rigjax.Project, name: str) -> rigjax.Project:
    """A project of a side-by-side frame's halves in Hugin's form of a dual-fisheye template: both
    i lines the whole frame ``name`` (twice as wide: the hfov, over the width, twice too), each
    lens's centre and vignetting centre shifted into its half, its crop the half, its vignetting
    over the whole frame's half diagonal (Hugin's r^2 is over the image's half diagonal squared)."""
    images = []
    for k, image in enumerate(project.images):
        width, height = image.width, image.height
        ratio = ((2 * width) ** 2 + height**2) / (width**2 + height**2)  # of the half diagonals squared
        images.append(
            image.replace(
                width=2 * width,
                hfov=2 * image.hfov,
                d=image.d + (k - 0.5) * width,
                vignetting_x=image.vignetting_x + (k - 0.5) * width,
                vignetting_b=image.vignetting_b * ratio,
                vignetting_c=image.vignetting_c * ratio**2,
                vignetting_d=image.vignetting_d * ratio**3,
                crop=(k * width, (k + 1) * width, 0, image.height),
                filename=name,
                links={},
            )
        )
    return project.replace(images=tuple(images))


@pytest.mark.parametrize("mode", ["template", "depth"])
def test_hugins_form_of_the_rig_stitches_the_clip_as_its_halves_do(dual, tmp_path, mode):
    """Every i line the whole side-by-side frame, each lens cropped to its half: the same rays
    (through rigjax), so the same panoramas as the project of the halves, frame for frame, but in
    the seam ring (the depth-aware mode: within two grey levels). There the lenses' circles differ by a pixel: Hugin centres a crop between its
    bounds, (0 + 128) / 2 = 64, half a pixel from the half's centre, 63.5, and the circle kept
    within the crop's is that much smaller than the halves' content."""
    _, rig, clip = dual
    halves = rigjax.load_project(rig)
    hugin = hugin_form(halves, "frame.png")
    hugin.save(tmp_path / "hugin.pto")
    xy = np.stack(np.meshgrid(np.arange(0, SIZE, 7.0), np.arange(0, SIZE, 7.0)), -1).reshape(-1, 2)
    for k in range(2):
        ray, ok = rigjax.img_to_ray(halves.cameras().take(k), xy)
        hugin_ray, hugin_ok = rigjax.img_to_ray(hugin.cameras().take(k), xy + [k * SIZE, 0])
        np.testing.assert_allclose(np.asarray(hugin_ray)[np.asarray(ok)], np.asarray(ray)[np.asarray(ok)], atol=1e-9)
    options = {"width": WIDTH, "mode": mode, "duration": 3 / RATE, "template_cache": False}
    if mode == "depth":
        options |= {"model": "sweep", "config": SMALL}
    as_halves = dict(video_panoramas(rig, [clip], **options))
    as_hugin = dict(video_panoramas(tmp_path / "hugin.pto", [clip], **options))
    assert sorted(as_hugin) == sorted(as_halves) == [0, 1, 2]
    if mode == "template":  # without its crops nothing keeps a lens to its half: refused
        uncropped = hugin.replace(images=(hugin.images[0], hugin.images[1].replace(crop=None)))
        uncropped.save(tmp_path / "uncropped.pto")
        with pytest.raises(
            ValueError, match=r"uncropped.pto: every i line states the whole 256 x 128 frame .* image 1 has no crop"
        ):
            VideoStitch.prepare(tmp_path / "uncropped.pto", [clip], width=WIDTH, mode="template")
    axis = np.asarray(halves.cameras().world_from_cam)[0, :, 2]
    off_axis = np.degrees(np.arccos(np.clip(np.asarray(pano_rays(WIDTH, WIDTH // 2)) @ axis, -1.0, 1.0)))
    ring = np.abs(off_axis - 90.0) < 6.0  # the seam ring of two 190-degree lenses, and a margin
    for t in as_halves:
        difference = np.abs(as_hugin[t].astype(int) - as_halves[t])
        # The depth-aware mode's colour fit and depth read the overlap: a grey level of it reaches further.
        assert difference[~ring].max() <= (0 if mode == "template" else 2), f"frame {t}"
        assert difference[ring].mean() < 2.0


def test_the_written_video_has_the_frames_rate_audio_and_360_metadata(dual, tmp_path):
    _, rig, clip = dual
    out = tmp_path / "pano.mp4"
    report = stitch_video(
        rig, [clip], out, width=WIDTH, mode="template", time_s=2 / RATE, duration=8 / RATE, segment_frames=3
    )
    assert report.frames == 8 and report.audio and not report.warnings
    assert not (tmp_path / "pano.mp4.parts").exists()
    with av.open(str(out)) as container:
        video = container.streams.video[0]
        assert video.average_rate == RATE and (video.width, video.height) == (WIDTH, WIDTH // 2)
        assert len(list(container.decode(video))) == 8

    # The audio packets are the source's over frames 2 .. 9, copied.
    copied = audio_packets(out)
    source = audio_packets(clip, 2 / RATE, 10 / RATE)
    assert copied == source and len(copied) >= 4
    [track] = mp4_boxes.spherical(out)
    assert track["v1"][0]["ProjectionType"] == "equirectangular" and track["v1"][0]["Spherical"] == "true"
    assert track["stereo_mode"] == [0] and track["sv3d"][0]["bounds"] == (0, 0, 0, 0)


def test_h265_is_written_as_apple_players_read_it(dual, tmp_path):
    """H.265 in MP4 under the 'hvc1' sample entry (Apple's players refuse FFmpeg's default 'hev1'),
    across segments and the join, with the spherical metadata in it."""
    _, rig, clip = dual
    out = tmp_path / "pano.mp4"
    encoding = Encoding(codec="h265", crf=28)
    report = stitch_video(
        rig, [clip], out, width=WIDTH, mode="template", duration=5 / RATE, segment_frames=2, encoding=encoding
    )
    assert report.frames == 5
    [track] = mp4_boxes.spherical(out)
    assert track["entries"] == ["hvc1"] and track["v1"][0]["ProjectionType"] == "equirectangular"
    with av.open(str(out)) as container:
        assert container.streams.video[0].codec_context.name == "hevc" and len(list(container.decode(video=0))) == 5


@pytest.mark.parametrize("frames", [1, 2])
def test_a_segment_of_one_or_two_h265_frames_is_written(tmp_path, frames):
    """x265 gives a sequence of one or two frames garbage decoding times now and then (the muxer
    refused about one segment in 20 here): the segment writer must write it every time."""
    from learnstitch.video.colour import Colour
    from learnstitch.video.sink import SegmentWriter

    for trial in range(40):
        path = tmp_path / f"segment-{trial}.mp4"
        writer = SegmentWriter(path, 0, 256, 128, Fraction(RATE), Encoding(codec="h265", crf=28), Colour(1, 1, 1, 1))
        for k in range(frames):
            writer.write(np.full((128, 256, 3), 40 * k, np.uint8))
        writer.close()
        with av.open(str(path)) as container:
            assert len(list(container.decode(video=0))) == frames


def test_a_pair_of_clips_shifted_by_k_frames_is_found_at_k(tmp_path):
    rng = np.random.default_rng(5)
    frames = [rng.integers(0, 255, (32, 64, 3), dtype=np.uint8) for _ in range(40)]
    sound = noise(40 * SPF, seed=7)
    k = 7
    a = write_clip(tmp_path / "a.mp4", frames, audio=sound)
    b = write_clip(tmp_path / "b.mp4", frames[k:], audio=sound[k * SPF :])  # started k frames later
    found = audio_offsets([str(a), str(b)])
    assert found.offsets == [k, 0]
    assert found.lags[1] == pytest.approx(k / RATE, abs=0.5 / RATE)
    assert audio_offsets([str(b), str(a)]).offsets == [0, k]


def test_a_run_killed_midway_resumes_to_the_same_frames(dual, tmp_path):
    _, rig, clip = dual
    args = ["stitch", "--rig", str(rig), "--video", str(clip), "--width", str(WIDTH), "--sweep"]
    args += ["--render", f"working_width={SMALL.working_width}", f"depth_planes={SMALL.depth_planes}"]
    args += ["--segment-frames", "2", "--no-audio", "--quiet"]
    # Every run a command of its own, as a user's: this process computes its camera maps in float64
    command = [sys.executable, "-m", "learnstitch.cli", *args]
    subprocess.run([*command, "-o", str(tmp_path / "whole.mp4")], check=True, capture_output=True)
    out = tmp_path / "pano.mp4"
    kill_after = random.Random(11).randint(1, 4)  # complete segments before the kill
    process = subprocess.Popen([*command, "-o", str(out)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    target = tmp_path / "pano.mp4.parts" / f"segment-{kill_after - 1:05d}.mp4"
    deadline = time.monotonic() + 300
    while not target.exists() and process.poll() is None and time.monotonic() < deadline:
        time.sleep(0.005)
    process.send_signal(signal.SIGKILL)
    process.wait()
    assert not out.exists() and target.exists()  # killed midway: whole segments, no video yet
    whole = len(list((tmp_path / "pano.mp4.parts").glob("segment-*.mp4")))
    resume = subprocess.run([*command, "-o", str(out), "--resume"], capture_output=True, text=True)
    assert resume.returncode == 0, resume.stderr
    assert f"stitched {FRAMES - 2 * whole} frames" in resume.stdout  # from the first missing segment on
    resumed, uninterrupted = decode_rgb(out), decode_rgb(tmp_path / "whole.mp4")
    assert len(resumed) == len(uninterrupted) == FRAMES
    for a, b in zip(resumed, uninterrupted):
        np.testing.assert_array_equal(a, b)


def test_a_stream_cut_midway_is_stitched_to_its_last_frame(dual, tmp_path):
    _, rig, clip = dual
    frames = decode_rgb(clip)
    cut = write_clip(
        tmp_path / "cut.mp4", frames, faststart=True
    )  # the index first: the frames end where the file does
    data = cut.read_bytes()
    cut.write_bytes(data[: int(len(data) * 0.6)])
    report = stitch_video(rig, [cut], tmp_path / "pano.mp4", width=WIDTH, mode="template", segment_frames=4)
    assert 0 < report.frames < FRAMES
    [warning] = report.warnings
    assert str(cut) in warning and f"frame {report.frames} " in warning
    assert len(decode_rgb(tmp_path / "pano.mp4")) == report.frames


@pytest.mark.parametrize(
    "case, pattern",
    [
        ("not a video", r"text\.mp4: not a video FFmpeg can read"),
        (
            "wrong size",
            r"wide\.mp4: 200 x 128 frames do not cut into the 2 images of .*rig\.pto \(128 x 128, 128 x 128",
        ),
        ("two rates", r"b25\.mp4: 25\.000 frames per second, but .*a30\.mp4 has 30\.000"),
        ("no frames", r"clip\.mp4: no frame at 100\.000 s \(frame 3000; the clip has 12 frames, 0\.400 s\)"),
    ],
)
def test_bad_input_is_one_line_naming_the_file_and_nothing_is_written(dual, tmp_path, capsys, case, pattern):
    _, rig, clip = dual
    videos, extra = [str(clip)], []
    if case == "not a video":
        videos = [str(tmp_path / "text.mp4")]
        Path(videos[0]).write_text("not a video\n")
    elif case == "wrong size":
        videos = [str(write_clip(tmp_path / "wide.mp4", [np.zeros((128, 200, 3), np.uint8)] * 2))]
    elif case == "two rates":
        half = [np.zeros((SIZE, SIZE, 3), np.uint8)] * 3
        videos = [str(write_clip(tmp_path / "a30.mp4", half)), str(write_clip(tmp_path / "b25.mp4", half, rate=25))]
        extra = ["--offsets", "0", "0"]
    elif case == "no frames":
        extra = ["--time", "100"]
    out = tmp_path / "pano.mp4"
    status = main(["stitch", "--rig", str(rig), "--video", *videos, "-o", str(out), "--mode", "template", *extra])
    err = capsys.readouterr().err.strip()
    assert status == 2 and len(err.splitlines()) == 1
    assert err.startswith("learnstitch stitch: error: ") and re.search(pattern, err), err
    assert not out.exists() and not (tmp_path / "pano.mp4.parts").exists()


def test_settings_are_checked_before_a_frame_is_stitched(dual, tmp_path):
    _, rig, clip = dual
    with pytest.raises(ValueError, match=r"preset must be one of"):
        Encoding(preset="quick")
    with pytest.raises(ValueError, match=r"--width must be a multiple of 4"):
        stitch_video(rig, [clip], tmp_path / "p.mp4", width=258, mode="template")
    with pytest.raises(ValueError, match=r"p\.avi: the 360 video is written as MP4"):
        stitch_video(rig, [clip], tmp_path / "p.avi", mode="template")
    assert os.listdir(tmp_path) == []
    assert Fraction(RATE) == VideoStitch.prepare(rig, [clip], width=WIDTH, mode="template").rate


def test_video_options_without_video_are_an_error(capsys):
    from learnstitch.cli import video_defaults

    assert {"mode", "depth_every", "crf", "resume", "quiet"} <= set(video_defaults())
    assert main(["stitch", "--rig", "rig.pto", "-o", "pano.jpg", "--depth-every", "3"]) == 2
    assert "--depth-every needs --video" in capsys.readouterr().err


def test_audio_an_mp4_cannot_hold_is_encoded_as_aac(dual, tmp_path):
    _, rig, clip = dual
    frames = decode_rgb(clip)[:6]
    mov = tmp_path / "pcm.mov"
    with av.open(str(mov), "w") as out:  # a MOV with 16-bit PCM, as some cameras record
        video = out.add_stream("libx264", rate=RATE, options={"crf": "0"})
        video.height, video.width, video.pix_fmt = SIZE, 2 * SIZE, "yuv420p"
        sound = out.add_stream("pcm_s16le", rate=AUDIO_RATE, layout="mono")
        for i, rgb in enumerate(frames):
            frame = av.VideoFrame.from_ndarray(rgb, format="rgb24")
            frame.pts = i
            out.mux(video.encode(frame))
            chunk = av.AudioFrame.from_ndarray(
                (noise(SPF, seed=i)[None] * 3e4).astype(np.int16), format="s16", layout="mono"
            )
            chunk.sample_rate, chunk.pts = AUDIO_RATE, i * SPF
            out.mux(sound.encode(chunk))
        out.mux(video.encode(None))
        out.mux(sound.encode(None))
    report = stitch_video(rig, [mov], tmp_path / "pano.mp4", width=WIDTH, mode="template")
    assert report.audio and report.frames == 6
    with av.open(str(tmp_path / "pano.mp4")) as container:
        heard = container.streams.audio[0]
        samples = sum(frame.samples for frame in container.decode(heard))
        assert heard.codec_context.name == "aac"
    assert abs(samples - 6 * SPF) <= 2048  # the clip's 0.2 s, give or take the encoder's frames


ORANGE = (250, 90, 40)  # a colour whose BT.601 and BT.709 readings differ by ten levels of luma
NEUTRAL = {IMAGE_FIELDS[letter]: IMAGE_DEFAULTS[letter] for letter in PHOTOMETRIC_LETTERS}  # Hugin's defaults


def yuv_of(rgb, matrix):
    """Limited-range Y, Cb, Cr of an RGB colour by the standards' formulas (BT.601 or BT.709)."""
    kr, kb = {"601": (0.299, 0.114), "709": (0.2126, 0.0722)}[matrix]
    r, g, b = (c / 255.0 for c in rgb)
    y = kr * r + (1 - kr - kb) * g + kb * b
    return 16 + 219 * y, 128 + 224 * (b - y) / (2 * (1 - kb)), 128 + 224 * (r - y) / (2 * (1 - kr))


def flat_yuv_frame(width, height, yuv):
    planes = np.empty((height * 3 // 2, width), np.uint8)  # PyAV's yuv420p layout: Y, then U and V
    planes[:height], planes[height : height * 5 // 4], planes[height * 5 // 4 :] = (round(v) for v in yuv)
    return av.VideoFrame.from_ndarray(planes, format="yuv420p")


@pytest.mark.parametrize(("width", "height", "matrix"), [(1280, 720, "709"), (640, 480, "601"), (1152, 576, "601")])
def test_an_untagged_frame_is_read_as_players_read_it(width, height, matrix):
    """Players read untagged video as BT.709 from 1280 columns or 577 rows up, else BT.601: a frame
    holding ORANGE by that reading's formula is read back as ORANGE (FFmpeg alone reads BT.601)."""
    from learnstitch.video.colour import to_rgb

    frame = flat_yuv_frame(width, height, yuv_of(ORANGE, matrix))
    assert int(frame.colorspace) == 2  # untagged
    np.testing.assert_allclose(to_rgb(frame)[height // 2, width // 2], ORANGE, atol=3)


@pytest.mark.parametrize("source", ["bt709", "rgb"])
@pytest.mark.parametrize("mode", ["template", "depth"])
def test_the_panoramas_keep_a_tagged_source_colour_and_say_so(dual, tmp_path, mode, source):
    """A side-by-side clip of one flat colour, encoded in BT.709 and tagged so (small enough that an
    untagged one would read as BT.601), or in RGB (libx264rgb): the stitched file's planes hold the
    colour's BT.709 values by the formula, and its stream is tagged BT.709, limited range. The rig's
    photometry is neutral: the depth-aware mode would undo a stated one (test_fullres.py)."""
    _, truth, _ = dual
    rig = tmp_path / "neutral.pto"
    project = rigjax.load_project(truth)
    project.replace(images=tuple(image.replace(**NEUTRAL) for image in project.images)).save(rig)
    clip = tmp_path / f"{source}.mp4"
    with av.open(str(clip), "w", format="mp4") as out:
        codec, pix_fmt = ("libx264", "yuv420p") if source == "bt709" else ("libx264rgb", "rgb24")
        video = out.add_stream(codec, rate=RATE, options={"crf": "0", "preset": "ultrafast"})
        video.width, video.height, video.pix_fmt = 2 * SIZE, SIZE, pix_fmt
        if source == "bt709":
            context = video.codec_context
            context.colorspace = context.color_primaries = context.color_trc = context.color_range = 1
        for i in range(3):
            if source == "bt709":
                frame = flat_yuv_frame(2 * SIZE, SIZE, yuv_of(ORANGE, "709"))
            else:
                frame = av.VideoFrame.from_ndarray(np.full((SIZE, 2 * SIZE, 3), ORANGE, np.uint8), format="rgb24")
            frame.pts = i
            out.mux(video.encode(frame))
        out.mux(video.encode(None))
    out = tmp_path / "pano.mp4"
    stitch_video(rig, [clip], out, width=WIDTH, mode=mode, model="sweep", config=SMALL, encoding=Encoding(crf=0))
    with av.open(str(out)) as container:
        frame = next(container.decode(video=0))
    assert (int(frame.colorspace), int(frame.color_range)) == (1, 1)
    assert (int(frame.color_primaries), int(frame.color_trc)) == (1, 1)
    planes = frame.to_ndarray().astype(float)  # the Y plane, then U and V as (H / 2, W / 2) each
    h = WIDTH // 2
    chroma = planes[h:].reshape(2, h // 2, WIDTH // 2)
    # The middle row, at the two lenses' centres (longitudes -90 and 90 degrees)
    got = [[planes[h // 2, x], *chroma[:, h // 4, x // 2]] for x in (WIDTH // 4, 3 * WIDTH // 4)]
    np.testing.assert_allclose(got, [yuv_of(ORANGE, "709")] * 2, atol=2.5)


def test_the_template_maps_are_kept_for_the_next_clip_of_the_rig(dual, tmp_path, monkeypatch):
    """The template's maps are made once per rig and kept: the next clip of the same rig reads
    them (the same frames, in a process that loads neither torch nor JAX); another calibration
    makes its own."""
    folder, rig, clip = dual
    cache = tmp_path / "cache"
    options = {"mode": "template", "width": WIDTH, "template_cache": cache}
    made = VideoStitch.prepare(rig, [clip], **options)
    kept = VideoStitch.prepare(rig, [clip], **options)
    assert "from the cache" not in made.notes[-1] and "from the cache" in kept.notes[-1]
    [entry] = cache.glob("*.npz")
    frames = next(iter(Footage(made.layout, 3, 1)))[1]
    np.testing.assert_array_equal(made(frames).to_ndarray(), kept(frames).to_ndarray())
    code = (
        "import sys\n"
        "from learnstitch.video import VideoStitch\n"
        f"stitch = VideoStitch.prepare({str(rig)!r}, [{str(clip)!r}], mode='template', width={WIDTH}, "
        f"template_cache={str(cache)!r})\n"
        "print(stitch.notes[-1])\n"
        "print(' '.join(m for m in ('torch', 'jax') if m in sys.modules))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.splitlines()[-2].endswith("(its maps from the cache)") and out.splitlines()[-1] == ""
    turned = tmp_path / "turned.pto"
    project = rigjax.load_project(rig)
    images = list(project.images)
    images[1] = dataclasses.replace(images[1], yaw=images[1].yaw + 1.0)
    project.replace(images=images).save(turned)
    other = VideoStitch.prepare(turned, [clip], **options)
    assert "from the cache" not in other.notes[-1] and len(list(cache.glob("*.npz"))) == 2
    assert np.abs(other(frames).to_ndarray().astype(int) - made(frames).to_ndarray()).max() > 20
    monkeypatch.setenv("LEARNSTITCH_CACHE_DIR", str(tmp_path / "default"))
    VideoStitch.prepare(rig, [clip], mode="template", width=WIDTH + 4, template_cache=False)
    assert len(list(cache.glob("*.npz"))) == 2 and not (tmp_path / "default").exists()
    made_again = VideoStitch.prepare(rig, [clip], mode="template", width=WIDTH + 4)  # the default cache
    assert "from the cache" not in made_again.notes[-1] and len(list((tmp_path / "default").rglob("*.npz"))) == 1
    entry.write_bytes(entry.read_bytes()[:4096])  # cut short (a full disk, say): made again, no error
    assert "from the cache" not in VideoStitch.prepare(rig, [clip], **options).notes[-1]
    assert "from the cache" in VideoStitch.prepare(rig, [clip], **options).notes[-1]
