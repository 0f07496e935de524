"""Retinomorphic event-driven representations (EDR) of video, and the paper's experiments."""

from pathlib import Path

__version__ = "0.1.0"
CONF_DIR = str(Path(__file__).resolve().parent / "conf")  # the Hydra configs, shipped inside
