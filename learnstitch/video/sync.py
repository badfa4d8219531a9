"""The offsets between a rig's clips, found from their audio: cameras started by hand start a few
frames apart, and every camera records the same sound.

Each clip's audio (its first ``seconds``, mixed to mono at ``rate`` Hz, timed from the clip's first
video frame) is cross-correlated with the first clip's; the lag of the correlation's peak is how
much later one clip started. Offsets are whole frames: rig frame 0 is frame ``offsets[k]`` of clip
``k``, the clip that started last at its frame 0.

Convention. Clip ``k`` started ``lag_k`` seconds after clip 0 when a sound at ``t`` seconds into
clip 0 is heard at ``t - lag_k`` into clip ``k``; ``offsets[k] = round((max lag - lag_k) fps)``.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import TYPE_CHECKING, NamedTuple

import av
import numpy as np

from .source import Layout, probe, rig_layout

if TYPE_CHECKING:
    import rigjax

# Below this peak correlation (normalised, 0-1) the clips are taken not to share a sound.
MIN_PEAK = 0.2


def audio_track(path: str, seconds: float, rate: int = 8000) -> np.ndarray | None:
    """The first ``seconds`` of a clip's audio, mono float32 at ``rate`` Hz from its first video
    frame (silence before the audio starts); None where the clip has no audio."""
    with av.open(path) as container:
        if not container.streams.audio:
            return None
        stream, video = container.streams.audio[0], container.streams.video[0]
        lead = float((stream.start_time or 0) * stream.time_base - (video.start_time or 0) * video.time_base)
        resampler = av.AudioResampler(format="flt", layout="mono", rate=rate)
        chunks, total = [], 0
        for frame in container.decode(stream):
            for out in resampler.resample(frame):
                chunk = out.to_ndarray().reshape(-1)
                chunks.append(chunk)
                total += chunk.size
            if total >= (seconds + abs(lead)) * rate:
                break
    samples = np.concatenate(chunks) if chunks else np.zeros(0, np.float32)
    shift = int(round(lead * rate))
    samples = np.concatenate([np.zeros(shift, np.float32), samples]) if shift > 0 else samples[-shift:]
    return samples[: int(seconds * rate)]


class AudioOffsets(NamedTuple):
    offsets: list[int]  # frames, one per clip
    lags: list[float]  # seconds each clip started after the first
    peaks: list[float]  # normalised correlation at each lag (1 for the first clip)

    @property
    def summary(self) -> str:
        return "correlation " + ", ".join(f"{p:.2f}" for p in self.peaks[1:])


def lag_seconds(reference: np.ndarray, other: np.ndarray, rate: int) -> tuple[float, float]:
    """How many seconds after ``reference`` ``other`` started (module docstring) and the
    normalised correlation at that lag."""
    a, b = reference - reference.mean(), other - other.mean()
    size = 1 << int(np.ceil(np.log2(len(a) + len(b))))
    correlation = np.fft.irfft(np.fft.rfft(a, size) * np.conj(np.fft.rfft(b, size)), size)
    # correlation[k] = sum a[n + k] b[n]: other's sample n is reference's n + k, so other started k later
    lags = np.concatenate([np.arange(0, len(a)), np.arange(-len(b) + 1, 0)])
    values = np.concatenate([correlation[: len(a)], correlation[size - len(b) + 1 :]])
    best = int(np.argmax(values))
    norm = float(np.sqrt((a * a).sum() * (b * b).sum())) or 1.0
    return lags[best] / rate, float(values[best] / norm)


def audio_offsets(paths: Sequence[str], seconds: float = 20.0, rate: int = 8000) -> AudioOffsets | None:
    """The clips' offsets from their audio (module docstring); None where a clip has no audio or
    the sounds do not match (peak correlation under :data:`MIN_PEAK`)."""
    fps = float(probe(paths[0]).rate)
    tracks = [audio_track(p, seconds, rate) for p in paths]
    if any(t is None or t.size < rate // 4 for t in tracks):
        return None
    lags, peaks = [0.0], [1.0]
    for track in tracks[1:]:
        lag, peak = lag_seconds(tracks[0], track, rate)
        lags.append(lag)
        peaks.append(peak)
    if min(peaks) < MIN_PEAK:
        return None
    latest = max(lags)
    return AudioOffsets([int(round((latest - lag) * fps)) for lag in lags], lags, peaks)


def footage_layout(
    project: rigjax.Project, videos: Sequence[str | os.PathLike], offsets: Sequence[int] | None
) -> tuple[Layout, list[str]]:
    """The layout of ``project``'s rig over its clips (:func:`~learnstitch.video.source.rig_layout`),
    ``offsets`` None found from the clips' audio where there is more than one, and notes saying so."""
    notes: list[str] = []
    paths = [os.fspath(v) for v in videos]
    if offsets is None and len(paths) > 1:
        found = audio_offsets(paths)
        if found is not None:
            offsets = found.offsets
            notes.append(f"offsets from the clips' audio: {' '.join(map(str, offsets))} frames ({found.summary})")
        else:
            notes.append("no audio in every clip to find their offsets: offsets 0 (give --offsets)")
    return rig_layout(project, paths, offsets), notes
