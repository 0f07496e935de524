"""Temporal representations of video: EDR and the baselines of the paper's Table 2.

Every class maps a clip (B, T, C, H, W) to (B, T', C_out, H, W) and says its sizes through
``out_channels(C)`` and ``out_frames(T)``.
"""

from edr.representations.base import Representation
from edr.representations.brox import BroxFlow
from edr.representations.dvs import DVSCamera, DVSSimulator, events_to_frames
from edr.representations.edr import EDR, EDRState
from edr.representations.frames import FDR, GrayDiff, RGBDiff
from edr.representations.mpeg_flow import MPEGFlow, decode_motion_vectors
from edr.representations.optical_flow import TVL1, Farneback
from edr.representations.wrappers import ClipTransform, EDRObservation

__all__ = [
    "EDR",
    "FDR",
    "TVL1",
    "BroxFlow",
    "ClipTransform",
    "DVSCamera",
    "DVSSimulator",
    "EDRObservation",
    "EDRState",
    "Farneback",
    "GrayDiff",
    "MPEGFlow",
    "RGBDiff",
    "Representation",
    "decode_motion_vectors",
    "events_to_frames",
]
