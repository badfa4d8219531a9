"""Spherical metadata (learnstitch.video.spherical): clips written by PyAV, marked, then read back by an
independent box reader (tests/learnstitch/mp4_boxes.py) and by FFmpeg itself, and decoded to the same
frames; bad files refused with the file named and left byte-identical."""

from __future__ import annotations

import shutil
import struct
from pathlib import Path

import av
import cv2
import mp4_boxes  # tests/learnstitch/mp4_boxes.py, the independent reader
import numpy as np
import pytest

from learnstitch.video.spherical import SphericalError, inject_spherical

FRAMES, WIDTH, HEIGHT = 12, 64, 32
# name: (suffix, codec, container options, the sample entry PyAV's muxer writes, moov before mdat)
CLIPS = {
    "h264": (".mp4", "libx264", {}, "avc1", False),
    "h264-faststart": (".mp4", "libx264", {"movflags": "faststart"}, "avc1", True),
    "h265": (".mp4", "libx265", {}, "hev1", False),
    "h264-mov": (".mov", "libx264", {}, "avc1", False),
}
V1 = {"Spherical": "true", "Stitched": "true", "StitchingSoftware": "learnstitch", "ProjectionType": "equirectangular"}
V2 = {"source": "learnstitch", "pose": (0.0, 0.0, 0.0), "bounds": (0, 0, 0, 0), "versions": (0, 0, 0)}


def frame_rgb(index: int) -> np.ndarray:
    """Frame ``index``: its number as the grey level of the top half, a horizontal gradient below."""
    rgb = np.zeros((HEIGHT, WIDTH, 3), np.uint8)
    rgb[: HEIGHT // 2] = 10 + 20 * index
    rgb[HEIGHT // 2 :] = (np.arange(WIDTH, dtype=np.uint8) * 4)[None, :, None]
    return rgb


def write_clip(path: Path, codec: str, options: dict[str, str]) -> None:
    with av.open(str(path), "w", options=options) as container:
        stream = container.add_stream(codec, rate=12)
        stream.width, stream.height, stream.pix_fmt = WIDTH, HEIGHT, "yuv420p"
        if codec == "libx265":
            stream.options = {"x265-params": "log-level=none"}
        for index in range(FRAMES):
            container.mux(stream.encode(av.VideoFrame.from_ndarray(frame_rgb(index), format="rgb24")))
        container.mux(stream.encode())


def decode(path: Path) -> list[np.ndarray]:
    with av.open(str(path)) as container:
        return [frame.to_ndarray(format="yuv420p") for frame in container.decode(video=0)]


@pytest.fixture(scope="module")
def clips(tmp_path_factory) -> dict[str, tuple[Path, list[np.ndarray]]]:
    """Each clip of CLIPS, written once, and its decoded frames before any metadata."""
    folder = tmp_path_factory.mktemp("clips")
    written = {}
    for name, (suffix, codec, options, _, _) in CLIPS.items():
        path = folder / f"{name}{suffix}"
        write_clip(path, codec, options)
        written[name] = (path, decode(path))
    return written


@pytest.fixture(params=sorted(CLIPS))
def clip(request, clips, tmp_path) -> tuple[str, Path, Path]:
    """A clip's name, its original and a copy in ``tmp_path`` to mark."""
    original = clips[request.param][0]
    copy = tmp_path / original.name
    shutil.copyfile(original, copy)
    return request.param, original, copy


def test_players_read_v1_and_v2(clip):
    name, original, path = clip
    _, _, _, entry, moov_first = CLIPS[name]
    order = mp4_boxes.top_level(original)
    assert (order.index("moov") < order.index("mdat")) == moov_first  # the case tests what it claims
    assert mp4_boxes.spherical(original) == [{"entries": [entry], "v1": [], "stereo_mode": [], "sv3d": []}]
    inject_spherical(path)
    assert mp4_boxes.top_level(path) == order
    assert mp4_boxes.spherical(path) == [{"entries": [entry], "v1": [V1], "stereo_mode": [0], "sv3d": [V2]}]


def same_media(original: Path, path: Path, frames: list[np.ndarray], moov_first: bool) -> None:
    """``path`` decodes to ``frames``, numbered in order, and its chunk offsets point at the bytes of
    ``original``'s, moved by the growth of the file when ``moov`` comes first."""
    after = decode(path)
    assert len(after) == FRAMES
    assert all(np.array_equal(a, b) for a, b in zip(frames, after))
    luma_top = [float(frame[: HEIGHT // 2].mean()) for frame in after]  # the frame numbers
    assert np.allclose(luma_top, 16 + (10 + 20 * np.arange(FRAMES)) * 219 / 255, atol=3)
    shift = path.stat().st_size - original.stat().st_size if moov_first else 0
    old_data, new_data = original.read_bytes(), path.read_bytes()
    for old, new in zip(mp4_boxes.chunk_offsets(original), mp4_boxes.chunk_offsets(path), strict=True):
        assert new == [offset + shift for offset in old]
        assert all(old_data[o : o + 64] == new_data[n : n + 64] for o, n in zip(old, new))


def test_frames_and_chunks_unchanged(clip, clips):
    name, original, path = clip
    inject_spherical(path)
    same_media(original, path, clips[name][1], CLIPS[name][4])


def largesize_mdat(path: Path) -> bytes:
    """The file with FFmpeg's 8-byte ``free`` and the ``mdat`` header after it merged into one 64-bit
    (``largesize``) ``mdat`` header: the media data stays where it was."""
    data, root = mp4_boxes.read_tree(path)
    kinds = [node.kind for node in root.children]
    free, mdat = root.children[kinds.index("free")], root.children[kinds.index("mdat")]
    assert (free.size, free.start + free.size) == (8, mdat.start)
    return data[: free.start] + struct.pack(">I4sQ", 1, b"mdat", mdat.size + 8) + data[mdat.body :]


def largesize_moov(path: Path) -> bytes:
    """The file (``moov`` last) with a 64-bit (``largesize``) ``moov`` header."""
    data, root = mp4_boxes.read_tree(path)
    (moov,) = root.all("moov")
    assert moov.start + moov.size == len(data)
    return data[: moov.start] + struct.pack(">I4sQ", 1, b"moov", moov.size + 8) + data[moov.body :]


def moov_to_end(path: Path) -> bytes:
    """The file (``moov`` last) with ``moov``'s size 0: "to the end of the file"."""
    data, root = mp4_boxes.read_tree(path)
    (moov,) = root.all("moov")
    assert moov.start + moov.size == len(data)
    return data[: moov.start] + bytes(4) + data[moov.start + 4 :]


def as_co64(path: Path) -> bytes:
    """The file with its ``stco`` rewritten as ``co64`` (64-bit offsets), its ancestors' sizes grown, and
    its offsets moved by that growth when ``moov`` comes first."""
    data, root = mp4_boxes.read_tree(path)
    (stco,), (offsets,) = mp4_boxes.chunk_tables(path), mp4_boxes.chunk_offsets(path)
    grow, kinds = 4 * len(offsets), [node.kind for node in root.children]
    moved = grow if kinds.index("moov") < kinds.index("mdat") else 0
    co64 = struct.pack(
        f">I4sII{len(offsets)}Q", stco.size + grow, b"co64", 0, len(offsets), *(o + moved for o in offsets)
    )
    out = bytearray(data[: stco.start] + co64 + data[stco.start + stco.size :])
    nodes = list(root.children)
    while nodes:  # every ancestor of stco: they all start before it, so their headers did not move
        node = nodes.pop()
        if node.start < stco.start < node.start + node.size:
            struct.pack_into(">I", out, node.start, node.size + grow)
            nodes.extend(node.children)
    return bytes(out)


# variant: (the clip it rewrites, the rewrite)
BOX_FORMS = {
    "largesize-mdat": ("h264", largesize_mdat),
    "largesize-mdat-faststart": ("h264-faststart", largesize_mdat),
    "largesize-moov": ("h264", largesize_moov),
    "moov-to-end": ("h264", moov_to_end),
    "co64": ("h264", as_co64),
    "co64-faststart": ("h264-faststart", as_co64),
}


@pytest.mark.parametrize("form", sorted(BOX_FORMS))
def test_box_forms(form, clips, tmp_path):
    """64-bit box sizes, size 0 and 64-bit chunk offsets, in files FFmpeg reads like the originals."""
    name, rewrite = BOX_FORMS[form]
    original, path = tmp_path / f"original{form}.mp4", tmp_path / f"{form}.mp4"
    original.write_bytes(rewrite(clips[name][0]))
    same_media(clips[name][0], original, clips[name][1], CLIPS[name][4])  # the rewrite itself is sound
    shutil.copyfile(original, path)
    inject_spherical(path)
    assert mp4_boxes.spherical(path) == [{"entries": ["avc1"], "v1": [V1], "stereo_mode": [0], "sv3d": [V2]}]
    same_media(original, path, clips[name][1], CLIPS[name][4])


@pytest.mark.skipif(av.library_versions["libavcodec"] < (61,), reason="FFmpeg < 7 keeps stream side data off frames")
def test_ffmpeg_reads_v2(clip):
    _, original, path = clip
    inject_spherical(path)
    kinds = av.sidedata.sidedata.Type
    for file, marked in ((original, False), (path, True)):
        with av.open(str(file)) as container:
            side_data = next(container.decode(video=0)).side_data
            spherical, stereo = side_data.get(kinds.SPHERICAL), side_data.get(kinds.STEREO3D)
        assert (spherical is not None, stereo is not None) == (marked, marked)
    # AVSphericalMapping: projection (0: equirectangular), bounds, yaw, pitch, roll, padding
    assert np.frombuffer(bytes(spherical), "<u4")[:9].tolist() == [0] * 9
    assert np.frombuffer(bytes(stereo), "<u4")[0] == 0  # AVStereo3D.type: AV_STEREO3D_2D


def test_marking_again_replaces(clip):
    _, _, path = clip
    inject_spherical(path)
    once = path.read_bytes()
    inject_spherical(path)
    assert path.read_bytes() == once  # idempotent
    inject_spherical(path, software="Stitcher <2> & co")
    (track,) = mp4_boxes.spherical(path)
    assert [v1["StitchingSoftware"] for v1 in track["v1"]] == ["Stitcher <2> & co"]
    assert [v2["source"] for v2 in track["sv3d"]] == ["Stitcher <2> & co"]
    assert track["stereo_mode"] == [0]
    inject_spherical(path)
    assert path.read_bytes() == once


def refused(path: Path, match: str) -> None:
    """``inject_spherical`` refuses ``path`` naming it, and leaves it and its folder as they were."""
    before, listing = path.read_bytes(), sorted(path.parent.iterdir())
    with pytest.raises(SphericalError, match=match) as error:
        inject_spherical(path)
    assert str(path) in str(error.value)
    assert path.read_bytes() == before
    assert sorted(path.parent.iterdir()) == listing  # no temporary file left behind


def test_not_mp4(tmp_path):
    text = tmp_path / "notes.mp4"
    text.write_text("a panorama, not a video\n")
    refused(text, "not an MP4/MOV file")
    png = tmp_path / "pano.png"
    cv2.imwrite(str(png), np.zeros((8, 16, 3), np.uint8))
    refused(png, "not an MP4/MOV file")
    empty = tmp_path / "empty.mp4"
    empty.write_bytes(b"")
    refused(empty, "0 moov boxes")
    with pytest.raises(SphericalError, match="missing.mp4: no such file"):
        inject_spherical(tmp_path / "missing.mp4")


def test_truncated(clips, tmp_path):
    path = tmp_path / "cut.mp4"
    path.write_bytes(clips["h264"][0].read_bytes()[:-100])  # moov last: its end cut off
    refused(path, "runs past the end of the file")


def test_no_video_track(tmp_path):
    path = tmp_path / "sound.mp4"
    with av.open(str(path), "w") as container:
        stream = container.add_stream("aac", rate=48000)
        frame = av.AudioFrame.from_ndarray(np.zeros((1, 1024), np.float32), format="fltp", layout="mono")
        frame.sample_rate = 48000
        container.mux(stream.encode(frame))
        container.mux(stream.encode())
    refused(path, "no video track")


def test_unsupported_sample_entry(tmp_path):
    path = tmp_path / "mjpeg.mov"
    with av.open(str(path), "w") as container:
        stream = container.add_stream("mjpeg", rate=12)
        stream.width, stream.height, stream.pix_fmt = WIDTH, HEIGHT, "yuvj420p"
        container.mux(stream.encode(av.VideoFrame.from_ndarray(frame_rgb(0), format="rgb24")))
        container.mux(stream.encode())
    refused(path, r"unsupported video sample entry \['jpeg'\]")


def test_stco_overflow(clips, tmp_path):
    """A 32-bit chunk offset that would pass 4 GiB once a leading moov grows: refused, not wrapped."""
    path = tmp_path / "near-4gib.mp4"
    data = bytearray(clips["h264-faststart"][0].read_bytes())
    (stco,) = mp4_boxes.chunk_tables(clips["h264-faststart"][0])
    assert stco.kind == "stco"
    struct.pack_into(">I", data, stco.body + 8, 0xFFFFFF00)  # the first chunk, near the 32-bit limit
    path.write_bytes(data)
    refused(path, "would pass 4 GiB")


def test_software_with_nul(clips, tmp_path):
    path = tmp_path / "clip.mp4"
    shutil.copyfile(clips["h264"][0], path)
    with pytest.raises(SphericalError, match=r"clip.mp4: the software name 'a\\x00b' contains a NUL"):
        inject_spherical(path, software="a\0b")


def test_rewrite_keeps_the_mode(clips, tmp_path):
    path = tmp_path / "clip.mp4"
    shutil.copyfile(clips["h264-faststart"][0], path)
    path.chmod(0o640)
    inject_spherical(path)
    assert path.stat().st_mode & 0o777 == 0o640
    assert sorted(p.name for p in tmp_path.iterdir()) == ["clip.mp4"]  # the temporary file renamed over it
