"""360 video from a calibrated rig's clips: decode, stitch frame by frame with the depth filtered
over time (or a fixed template remap), encode in resumable segments with the audio and the
spherical metadata (:mod:`learnstitch.video.pipeline`)."""

from .pipeline import MODES, VideoReport, VideoStitch, stitch_video, video_panoramas
from .sink import Encoding
from .source import VideoError

__all__ = ["MODES", "Encoding", "VideoError", "VideoReport", "VideoStitch", "stitch_video", "video_panoramas"]
