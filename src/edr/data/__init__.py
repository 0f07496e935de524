"""Video input: decoding files and generating clips that need no download."""

from edr.data.synthetic import synthetic_scene
from edr.data.video import read_video, write_video

__all__ = ["read_video", "synthetic_scene", "write_video"]
