"""Retinomorphic event-driven representations (EDR) of video, and the paper's experiments."""

__version__ = "0.1.0"
