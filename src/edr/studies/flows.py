"""Optical flow against ground truth: frame pairs made by warping a real image with known flows.

``python -m edr.studies.flows`` writes a record, ``<out-dir>/flow_accuracy_<host>_<time>.json``,
and prints its table; ``edr-tables`` renders the newest into ``paper/flow_accuracy.md``: the
average endpoint error
(EPE, pixels) of Brox, TV-L1 and Farneback on four pairs made from the photograph matplotlib
ships (``grace_hopper.jpg``, gray, 320x240): a translation, a rotation, a zoom and a smooth
random field, each at most a few pixels, as between consecutive video frames.

Each second frame is the image resampled at ``y - w(y)`` (bicubic), so the image point
``x = y - w(y)`` moves to ``y``; the true flow *from the first frame* is then
``f(x) = w(x + f(x))``, solved by fixed-point iteration (the warp field is not the flow itself
except for a translation). The EPE leaves out a 20-pixel border, where content enters or leaves.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
import torch

from edr.report.flow_accuracy import KINDS, flow_accuracy_table
from edr.store.atomic import write_json_atomic
from edr.store.records import bench_dir, git_revision, machine_info

BORDER = 20  # pixels left out of the EPE on every side


def sample_image(width: int = 320, height: int = 240) -> np.ndarray:
    """The photograph matplotlib ships, gray, resized: (H, W) float32 in 0..255."""
    import matplotlib

    path = Path(matplotlib.get_data_path()) / "sample_data" / "grace_hopper.jpg"
    image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if image is None:
        raise FileNotFoundError(f"{path}: matplotlib's sample image is missing")
    return cv2.resize(image, (width, height), interpolation=cv2.INTER_AREA).astype(np.float32)


def warp_field(kind: str, height: int, width: int, seed: int = 0) -> np.ndarray:
    """The warp w (2, H, W) of one kind: second(y) = first(y - w(y))."""
    yy, xx = np.mgrid[0:height, 0:width].astype(np.float32)
    cx, cy = width / 2, height / 2
    if kind == "translation":
        return np.stack([np.full_like(xx, 2.3), np.full_like(yy, -1.4)])
    if kind == "rotation":  # 2 degrees about the centre
        a = np.deg2rad(2.0)
        u = np.cos(a) * (xx - cx) - np.sin(a) * (yy - cy) + cx - xx
        v = np.sin(a) * (xx - cx) + np.cos(a) * (yy - cy) + cy - yy
        return np.stack([u, v]).astype(np.float32)
    if kind == "zoom":  # 3 %
        return np.stack([0.03 * (xx - cx), 0.03 * (yy - cy)]).astype(np.float32)
    if kind == "smooth":  # Gaussian-smoothed noise, at most 3 px per component
        rng = np.random.default_rng(seed)
        parts = [
            cv2.GaussianBlur(rng.normal(0, 1, (height, width)).astype(np.float32), (0, 0), 25)
            for _ in range(2)
        ]
        return np.stack([3 * p / np.abs(p).max() for p in parts]).astype(np.float32)
    raise ValueError(f"kind must be one of {KINDS}, got {kind!r}")


def pair(image: np.ndarray, kind: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(first, second, true flow (2, H, W)) for one kind; frames (H, W) float32 0..255."""
    h, w = image.shape
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    field = warp_field(kind, h, w)
    second = cv2.remap(
        image, xx - field[0], yy - field[1], cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT
    )
    flow = field.copy()
    for _ in range(30):  # f(x) = w(x + f(x)); contracts while |grad w| < 1
        flow = np.stack(
            [
                cv2.remap(
                    c, xx + flow[0], yy + flow[1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE
                )
                for c in field
            ]
        )
    return image, np.clip(second, 0, 255), flow


def endpoint_error(estimate: np.ndarray, truth: np.ndarray) -> float:
    """Mean |estimate - truth| over the pixels BORDER or more from the edge; flows (2, H, W)."""
    error = np.sqrt(((estimate - truth) ** 2).sum(0))
    return float(error[BORDER:-BORDER, BORDER:-BORDER].mean())


def methods() -> dict[str, Callable[[torch.Tensor], torch.Tensor]]:
    """Each flow as the suite's representation: clip (1, 2, 1, H, W) uint8 -> (1, 1, 2, H, W)."""
    from edr.representations import TVL1, BroxFlow, Farneback

    return {"Brox": BroxFlow(), "TV-L1": TVL1(), "Farneback": Farneback()}


def evaluate(image: np.ndarray) -> dict[str, dict[str, float]]:
    """{method: {kind: EPE}} on the four pairs made from ``image``."""
    results: dict[str, dict[str, float]] = {}
    for kind in KINDS:
        first, second, truth = pair(image, kind)
        clip = torch.from_numpy(np.stack([first, second]).round().astype(np.uint8))[None, :, None]
        for name, flow in methods().items():
            estimate = flow(clip)[0, 0].numpy()
            results.setdefault(name, {})[kind] = endpoint_error(estimate, truth)
    return results


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        prog="python -m edr.studies.flows",
        description=__doc__.split("\n\n")[0],
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    parser.add_argument(
        "--out-dir",
        type=Path,
        default=bench_dir(),
        help="where the record is written (default: results/runs/bench, untracked)",
    )
    args = parser.parse_args(argv)
    stamp, machine = time.strftime("%Y-%m-%d_%H-%M-%S"), machine_info()
    record = {
        "kind": "flow_accuracy",
        "measured_at": stamp,
        "git": git_revision(),
        "machine": machine,
        "border": BORDER,
        "epe": evaluate(sample_image()),
    }
    path = write_json_atomic(
        args.out_dir / f"flow_accuracy_{machine['hostname']}_{stamp}.json", record
    )
    print(flow_accuracy_table(record, str(path)))


if __name__ == "__main__":
    main()
