"""Where the real KTH and UCF-101 clips lie: ``../shared/real-video`` beside the repository, or
``EDR_REAL_VIDEO``. Tests that read them skip where the folder is absent."""

from __future__ import annotations

import os
from pathlib import Path

REAL_VIDEO = Path(
    os.environ.get("EDR_REAL_VIDEO", Path(__file__).resolve().parents[2] / "shared" / "real-video")
)
