"""A stitched clip written as segments of frames, joined into one 360 video at the end.

Each segment (``segment_frames`` frames; the unit a batch runner distributes) is encoded into its
own MP4 in a folder beside the output (``pano.mp4.parts/``), written under a temporary name and
renamed when complete, so a run killed at any moment leaves only whole segments; ``--resume``
stitches from the first missing one. The join copies the segments' packets into one file without
re-encoding (their timestamps run on from one segment to the next), interleaves the source's audio
packets over the clip's time range, and writes Google's spherical metadata
(:mod:`learnstitch.video.spherical`) so that players show it as 360 degrees.

Convention. Output frame ``t`` (0 the first stitched frame) has presentation time ``t / rate``
seconds: the input's frame rate and, for a constant-rate input, its timestamps from the first
stitched frame. Audio packets are kept whole: those whose presentation time falls within the
stitched range, shifted by the range's start (an audio codec MP4 does not hold, such as PCM, is
encoded as AAC instead).
"""

from __future__ import annotations

import contextlib
import heapq
import json
import os
import uuid
from dataclasses import asdict, dataclass
from fractions import Fraction
from pathlib import Path
from typing import Any

import av
import numpy as np

from rigjax.errors import ConfigError

from .colour import Colour, from_rgb, to_yuv420
from .spherical import inject_spherical

ENCODERS = {"h264": "libx264", "h265": "libx265"}
# Frames a segment: ten seconds at 30 fps, a batch's chunk too. Each segment starts with a key
# frame and an encoder of its own, so segments shorter than x264's own key-frame interval (250
# frames) add key frames and encoder starts that one encode of the clip does not make.
SEGMENT_FRAMES = 300
# Audio codecs an MP4 holds, copied as they are; any other (PCM from a MOV, say) is encoded as AAC.
MP4_AUDIO = {"aac", "mp3", "mp2", "ac3", "eac3", "opus", "alac", "flac"}
PRESETS = ("ultrafast", "superfast", "veryfast", "faster", "fast", "medium", "slow", "slower", "veryslow")


@dataclass(frozen=True)
class Encoding:
    """How the panoramas are encoded: ``codec`` h264 (players' common ground) or h265, the x264 /
    x265 constant rate factor ``crf`` (0: lossless; 18: visually lossless; 23: x264's default) and
    speed ``preset`` (``veryfast`` by default: a 2-core machine keeps up with the stitch), and the
    encoder's ``threads`` (0: its own choice, from the machine's cores; x264's and x265's output
    depends on their thread count, so a batch whose chunks must not depend on the machine that
    encodes them pins it)."""

    codec: str = "h264"
    crf: int = 18
    preset: str = "veryfast"
    threads: int = 0

    def __post_init__(self) -> None:
        if self.codec not in ENCODERS:
            raise ConfigError(f"codec must be one of {sorted(ENCODERS)}, got {self.codec!r}")
        if not 0 <= self.crf <= 51:
            raise ConfigError(f"crf must be in 0..51, got {self.crf!r}")
        if self.preset not in PRESETS:
            raise ConfigError(f"preset must be one of {', '.join(PRESETS)}, got {self.preset!r}")
        if self.threads < 0:
            raise ConfigError(f"threads must be >= 0 (0: the encoder's own choice), got {self.threads!r}")

    def settings(self) -> dict[str, Any]:
        """As a run's manifest records it: ``threads`` only where pinned (a manifest written before
        it existed still matches)."""
        settings = asdict(self)
        if not self.threads:
            del settings["threads"]
        return settings

    def options(self) -> dict[str, str]:
        options = {"crf": str(self.crf), "preset": self.preset}
        if self.threads:
            options["threads"] = str(self.threads)
        if self.codec == "h265":
            options["x265-params"] = "log-level=error" + (":lossless=1" if self.crf == 0 else "")
        return options


def replace_atomically(partial: Path, final: Path) -> None:
    with open(partial, "rb") as f:
        os.fsync(f.fileno())
    os.replace(partial, final)


class SegmentWriter:
    """One segment's MP4 (``path``), frames ``first ..`` of the clip, encoded as they come, in
    ``colour`` (limited-range 4:2:0 in its matrix, tagged: :mod:`learnstitch.video.colour`)."""

    def __init__(
        self, path: Path, first: int, width: int, height: int, rate: Fraction, encoding: Encoding, colour: Colour
    ):
        self.path, self.first, self.frames, self.colour = path, first, 0, colour
        # a name of this writer's own: a chunk run again elsewhere while a lost worker still writes
        # it never shares its file; the complete segment is renamed into place
        self.partial = path.with_name(f"{path.name}.{uuid.uuid4().hex[:12]}.partial")
        self.container = av.open(str(self.partial), "w", format="mp4")
        stream = self.container.add_stream(ENCODERS[encoding.codec], rate=rate, options=encoding.options())
        stream.width, stream.height, stream.pix_fmt = width, height, "yuv420p"
        if encoding.codec == "h265":  # Apple's players and Safari play H.265 in MP4 as 'hvc1' only (FFmpeg: 'hev1')
            stream.codec_tag = "hvc1"
        stream.time_base = self.time_base = 1 / rate  # the muxer changes the stream's when it starts: keep ours
        context = stream.codec_context
        # Frame and slice threads, libavcodec's default and the ffmpeg command's: PyAV asks for slices
        # alone, and libx264 then splits every frame into slices over its threads instead of coding
        # frames side by side, slower on the same CPU
        context.thread_type = "AUTO"
        context.colorspace, context.color_range = colour.space, colour.range
        context.color_primaries, context.color_trc = colour.primaries, colour.trc
        self.stream = stream

    def write(self, frame: av.VideoFrame | np.ndarray) -> None:
        """Encode the segment's next frame: an ``(h, w, 3)`` uint8 RGB panorama, or a frame in the
        colour its tags say (converted to the segment's where it is not)."""
        frame = from_rgb(frame, self.colour) if isinstance(frame, np.ndarray) else to_yuv420(frame, self.colour)
        frame.pts = self.first + self.frames
        frame.time_base = self.time_base
        self._mux(self.stream.encode(frame))
        self.frames += 1

    def _mux(self, packets: list[av.Packet]) -> None:
        for packet in packets:
            if packet.pts is not None and (packet.dts is None or not packet.pts - 64 <= packet.dts <= packet.pts):
                # x265 gives a sequence of one or two frames decoding times read from memory it never
                # set (the muxer then refuses the packet); such a sequence is not reordered: each
                # frame is decoded when it is shown
                packet.dts = packet.pts
            self.container.mux(packet)

    def close(self) -> None:
        """Flush the encoder and rename the segment to its final name: complete."""
        self._mux(self.stream.encode(None))
        self.container.close()
        replace_atomically(self.partial, self.path)

    def abandon(self) -> None:
        with contextlib.suppress(Exception):
            self.container.close()
        self.partial.unlink(missing_ok=True)


class Segments:
    """The folder of a clip's segments and the settings they were made with (``manifest.json``):
    a resume continues only a run of the same settings."""

    def __init__(self, folder: Path, segment_frames: int, settings: dict[str, Any]):
        self.folder, self.segment_frames, self.settings = folder, segment_frames, settings

    def path(self, k: int) -> Path:
        return self.folder / f"segment-{k:05d}.mp4"

    def open(self, resume: bool) -> int:
        """Prepare the folder and return the first segment to stitch: 0, or with ``resume`` the
        first that is not complete. Without ``resume`` an earlier run's complete segments are an
        error (they would be lost)."""
        manifest = self.folder / "manifest.json"
        if self.complete() and not resume:
            raise ConfigError(
                f"{self.folder}: segments of an earlier run are there; pass --resume to continue it, or remove the folder"
            )
        if resume and manifest.exists():
            earlier = json.loads(manifest.read_text())
            if earlier != self.settings:
                changed = sorted(k for k in set(earlier) | set(self.settings) if earlier.get(k) != self.settings.get(k))
                raise ConfigError(
                    f"{self.folder}: --resume with other settings than the run it continues ({', '.join(changed)} "
                    "differ); rerun with the same ones, or remove the folder"
                )
        self.folder.mkdir(parents=True, exist_ok=True)
        for stale in self.folder.glob("*.partial"):
            stale.unlink()
        partial = manifest.with_suffix(".partial")
        partial.write_text(json.dumps(self.settings, indent=1, sort_keys=True))
        replace_atomically(partial, manifest)
        k = 0
        while self.path(k).exists():
            k += 1
        return k

    def complete(self) -> list[Path]:
        k, found = 0, []
        while self.path(k).exists():
            found.append(self.path(k))
            k += 1
        return found


@dataclass(frozen=True)
class AudioSource:
    """The audio kept: the stream of ``path`` over ``start .. start + seconds`` (None: to its end)."""

    path: str
    start: float
    seconds: float | None


def _packets(path: str, kind: str, since: float = 0.0, until: float | None = None, at: float = 0.0):
    """``(time, packet)`` of the first ``kind`` stream of ``path`` in order: those presented
    ``since .. until`` seconds after the file's first video frame, retimed so that ``since`` falls
    at ``at`` seconds (``time``: their new presentation time)."""
    with av.open(path) as container:
        video = container.streams.video[0]
        stream = getattr(container.streams, kind)[0]
        zero = (video.start_time or 0) * video.time_base  # the file's first frame, seconds
        shift = int(
            round(
                (Fraction(at).limit_denominator(1 << 20) - Fraction(since).limit_denominator(1 << 20) - zero)
                / stream.time_base
            )
        )
        for packet in container.demux(stream):
            if packet.pts is None or packet.size == 0:
                continue
            time = float(packet.pts * stream.time_base - zero)
            if time < since - 1e-6 or (until is not None and time >= until - 1e-6):
                continue
            packet.pts += shift
            if packet.dts is not None:
                packet.dts += shift
            yield time - since + at, packet


def join(
    segments: list[Path], starts: list[float], output: Path, audio: AudioSource | None, software: str = "learnstitch"
) -> None:
    """The ``segments``' packets copied into ``output`` in order, segment ``k`` from ``starts[k]``
    seconds, with ``audio``'s packets interleaved by time, then the spherical metadata; written
    under a temporary name and renamed."""
    partial = output.with_name(output.name + ".partial")
    try:
        with av.open(str(segments[0])) as first:
            template = first.streams.video[0]
            with av.open(str(partial), "w", format="mp4", options={"movflags": "+faststart"}) as out:
                video = out.add_stream_from_template(template)
                video.codec_tag = template.codec_tag  # the template leaves it out: 'hvc1' would become 'hev1'
                streams = [_to(_video_packets(segments, starts), video)]
                if audio is not None:
                    with av.open(audio.path) as source:
                        heard = source.streams.audio[0]
                        copied = heard.codec_context.name in MP4_AUDIO
                        if copied:
                            sound = out.add_stream_from_template(heard)
                        else:  # PCM and the like: MP4 does not hold them
                            sound = out.add_stream("aac", rate=heard.rate, layout=heard.layout, bit_rate=192000)
                    until = None if audio.seconds is None else audio.start + audio.seconds
                    packets = _packets(audio.path, "audio", audio.start, until)
                    streams.append(_to(packets, sound) if copied else _encoded(packets, sound))
                for _, packet in heapq.merge(*streams, key=lambda item: item[0]):
                    out.mux(packet)
        inject_spherical(partial, software=software)
        replace_atomically(partial, output)
    finally:
        partial.unlink(missing_ok=True)


def _timing(path: Path) -> tuple[list[int], Fraction]:
    """A segment's presentation times in order, from its first frame's, and the seconds by which
    its decoding times trail them (its B-frames' reorder delay)."""
    with av.open(str(path)) as container:
        stream = container.streams.video[0]
        stamps = [(p.pts, p.dts) for p in container.demux(stream) if p.pts is not None and p.dts is not None]
        first, tick = stream.start_time or 0, stream.time_base  # read while the file is open
    ordered = sorted(pts - first for pts, _ in stamps)
    stamps = [(pts - first, dts - first) for pts, dts in stamps]
    delay = max((Fraction(ordered[i] - dts) * tick for i, (_, dts) in enumerate(stamps)), default=Fraction(0))
    return ordered, delay


def _video_packets(segments: list[Path], starts: list[float]):
    """The segments' packets in order, retimed to their ``starts``, their decoding times made one
    sequence: each segment's sorted presentation times less the largest reorder delay of any (a
    short last segment has fewer B-frames than the rest; its own decoding times would jump). Each
    packet is muxed while its file is open (a packet outliving its demuxer is not safe to mux)."""
    timings = [_timing(path) for path in segments]
    delay = max(delay for _, delay in timings)
    for path, start, (ordered, _) in zip(segments, starts, timings):
        for k, (time, packet) in enumerate(_packets(str(path), "video", at=start)):
            # _packets put the segment's first frame at ``start``: its presentation times' retiming
            packet.dts = ordered[k] + round(Fraction(start).limit_denominator(1 << 20) / packet.time_base)
            packet.dts -= round(delay / packet.time_base)
            yield time, packet


def _encoded(items, stream):
    """``(time, packet)`` of ``stream``'s encoder fed the decoded audio of ``items``' packets, its
    samples counted from the range's start."""
    counted = 0
    for _, packet in items:
        for frame in packet.decode():  # while the packet's file is open
            frame.pts, frame.time_base = counted, Fraction(1, frame.sample_rate)
            counted += frame.samples
            for encoded in stream.encode(frame):
                yield float(encoded.pts * encoded.time_base), encoded
    for encoded in stream.encode(None):
        yield float(encoded.pts * encoded.time_base), encoded


def _to(items, stream):
    for time, packet in items:
        packet.stream = stream
        yield time, packet


def settings_of(**values: Any) -> dict[str, Any]:
    """Settings as the manifest stores them (JSON types)."""
    return json.loads(json.dumps({k: v.settings() if isinstance(v, Encoding) else v for k, v in values.items()}))
