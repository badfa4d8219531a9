"""360 video from a calibrated rig's clips: decode, stitch frame by frame with the depth filtered
over time (or a fixed template remap), encode in resumable segments with the audio and the
spherical metadata (:mod:`learnstitch.video.pipeline`); many clips chunk by chunk, here or on a
Ray cluster (:mod:`learnstitch.video.batch`)."""

from .batch import BatchReport, stitch_batch
from .chunks import Clip
from .pipeline import MODES, VideoReport, VideoStitch, stitch_video, video_panoramas
from .sink import Encoding
from .source import VideoError

__all__ = [
    "MODES",
    "BatchReport",
    "Clip",
    "Encoding",
    "VideoError",
    "VideoReport",
    "VideoStitch",
    "stitch_batch",
    "stitch_video",
    "video_panoramas",
]
