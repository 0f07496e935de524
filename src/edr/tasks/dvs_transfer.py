"""DVS transfer (the paper's Appendix A): a ConvNet+RCN trained on KTH with EDR takes
event-camera frames straight in — no EDR layer — and is fine-tuned on 70 % of them.

Event recordings come from disk (``dvs_root``: ``<root>/<action>/*.npz|*.aedat``) or, by
default, from the DVS simulator run on KTH videos (``streams_per_class`` per action). Both are
binned to one [ON, OFF] frame per video frame interval, like EDR's output.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn
from tqdm import tqdm

from edr import interrupts
from edr.atomic import write_json_atomic
from edr.data.clips import VideoSource, resize_clip, take_frames
from edr.data.datasets import VideoSet, resolve_root
from edr.data.events import list_recordings, read_recording
from edr.data.fingerprint import files_fingerprint
from edr.representations import EDR, DVSSimulator, events_to_frames
from edr.tasks.metrics import classification_metrics
from edr.tasks.plots import save_confusion
from edr.tasks.recognition import CONFUSION, Fitted
from edr.validate import ExistingDir, Fraction, NonNegativeInt, PositiveFloat, PositiveInt

KTH_SETTINGS = ("videos", "synthetic", "data_root", "cache_dir", "resize", "max_frames", "frames",
                "crop")  # fmt: skip


def kth_settings(pretrain: Callable[..., Fitted]) -> dict[str, Any]:
    """The KTH data settings the pre-training reads (its config's, else its defaults): the
    simulator records the same videos, decoded, resized and cropped as the network saw them."""
    parameters = inspect.signature(pretrain).parameters
    return {name: parameters[name].default for name in KTH_SETTINGS}


def _event_clip(
    events: np.ndarray, height: int, width: int, frame_us: float, frames: int, crop: int
) -> torch.Tensor:
    """Events -> (frames, 2, crop, crop) float32: [ON, OFF] counts per frame interval."""
    n_bins = max(1, int(np.ceil((int(events["t"].max()) + 1) / frame_us))) if len(events) else 1
    binned = events_to_frames(
        events, height, width, time_window=frame_us, start_time=0.0, end_time=n_bins * frame_us,
        dtype=np.float32,
    )  # fmt: skip
    clip = torch.from_numpy(binned[:, ::-1].copy())  # tonic's [OFF, ON] -> EDR's [ON, OFF]
    return resize_clip(take_frames(clip, 0, frames), crop)


def _sensor_size(events: np.ndarray, path: Path) -> tuple[int, int]:
    """(height, width): a DVS128's 128x128 for AEDAT, else what the events span."""
    if path.suffix == ".aedat" or not len(events):
        return 128, 128
    return int(events["y"].max()) + 1, int(events["x"].max()) + 1


def _split(labels: np.ndarray, train_fraction: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Seeded split of indices, per class, ``train_fraction`` of each class for training."""
    rng = np.random.default_rng(seed)
    train, test = [], []
    for label in np.unique(labels):
        members = rng.permutation(np.flatnonzero(labels == label))
        cut = round(train_fraction * len(members))
        train += members[:cut].tolist()
        test += members[cut:].tolist()
    return np.array(sorted(train)), np.array(sorted(test))


@torch.no_grad()
def _predict(backbone: nn.Module, clips: torch.Tensor, batch: int = 8) -> np.ndarray:
    backbone.eval()
    return np.concatenate(
        [backbone(clips[i : i + batch]).argmax(-1).numpy() for i in range(0, len(clips), batch)]
    )


def dvs_transfer(
    *,
    out_dir: Path,
    seed: int,
    pretrain: Callable[..., Fitted],
    optimizer: Callable[..., torch.optim.Optimizer],
    dvs_root: ExistingDir | None = None,
    simulator: dict[str, float] | None = None,
    streams_per_class: PositiveInt = 10,
    train_fraction: Fraction = 0.7,
    finetune_epochs: NonNegativeInt = 20,
    batch_size: PositiveInt = 8,
    event_scale: PositiveFloat = 1.0,
    resume: bool = False,
) -> dict[str, Any]:
    """Pre-train on KTH with EDR, then fine-tune and test on event-camera frames; returns metrics.

    The KTH videos the simulator records, and their frames and crop, are the pre-training's
    (``pretrain``'s settings). ``resume`` continues the pre-training from its checkpoint; fine-tuning is short and reruns.
    """
    # ---- 1. the ConvNet+RCN trained on KTH with EDR ------------------------------------------
    pretrain_dir = out_dir / "pretrain"
    pretrain_dir.mkdir(parents=True, exist_ok=True)
    model, pretrained = pretrain(out_dir=pretrain_dir, seed=seed, resume=resume)
    edr = model.representation
    if not isinstance(edr, EDR) or edr.out_channels(1) != 2:
        raise ValueError(
            "DVS transfer needs a network trained on EDR with one ON/OFF pair per pixel "
            "(representation=edr with color gray or gray video, one timescale or combine=sum)"
        )
    backbone = model.backbone

    # ---- 2. event recordings, as [ON, OFF] frames -------------------------------------------
    sim = DVSSimulator(**(simulator or {}))
    kth = kth_settings(pretrain)
    videos: Callable[..., VideoSet] = kth["videos"]
    frames, crop, cache_dir = kth["frames"], kth["crop"], kth["cache_dir"]
    root = resolve_root(kth["data_root"], kth["synthetic"], cache_dir)
    classes = videos(root, train=True).classes
    clips, labels = [], []
    if dvs_root:
        source_name = f"recordings under {dvs_root}"
        recordings = list_recordings(dvs_root, classes)
        fingerprint = files_fingerprint([p for p, _ in recordings], Path(dvs_root))
        for path, label in tqdm(recordings, desc="reading recordings", unit="file"):
            events = read_recording(path)
            h, w = _sensor_size(events, path)
            clips.append(_event_clip(events, h, w, sim.frame_us, frames, crop))
            labels.append(label)
    else:
        source_name = f"DVS simulator on {streams_per_class} videos per class of {root}"
        fingerprint = pretrained["data/fingerprint"]
        frame_source = VideoSource(
            cache_dir, size=tuple(kth["resize"]), gray=True, max_frames=kth["max_frames"]
        )
        pool = [v for split in (True, False) for v in videos(root, train=split).videos]
        chosen = [
            v
            for label in range(len(classes))
            for v in [u for u in pool if u.label == label][:streams_per_class]
        ]
        for video in tqdm(chosen, desc="simulating DVS", unit="video"):
            gray = np.asarray(frame_source(video.path))[:, 0]  # (T, H, W)
            h, w = gray.shape[1:]
            clips.append(_event_clip(sim.simulate(gray), h, w, sim.frame_us, frames, crop))
            labels.append(video.label)
    clips_t = torch.stack(clips) * event_scale  # (N, frames, 2, crop, crop)
    labels_np = np.array(labels)
    train_idx, test_idx = _split(labels_np, train_fraction, seed)
    if len(train_idx) == 0 or len(test_idx) == 0:
        raise ValueError(
            f"{len(labels_np)} recordings are too few for a {train_fraction:.0%} split"
        )

    # ---- 3. straight in, then fine-tuned ------------------------------------------------------
    zero_shot = _predict(backbone, clips_t[test_idx])
    opt = optimizer(backbone.parameters())
    loss_fn = nn.CrossEntropyLoss()
    train_x, train_y = clips_t[train_idx], torch.from_numpy(labels_np[train_idx])
    for _ in (bar := tqdm(range(finetune_epochs), desc="fine-tuning", unit="epoch")):
        backbone.train()
        order = torch.randperm(len(train_x))
        for i in range(0, len(order), batch_size):
            interrupts.raise_if_stopping()
            batch = order[i : i + batch_size]
            loss = loss_fn(backbone(train_x[batch]), train_y[batch])
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
        bar.set_postfix(loss=f"{loss.item():.3f}")
    predicted = _predict(backbone, clips_t[test_idx])
    true = labels_np[test_idx]
    scores, confusion = classification_metrics(predicted, true, classes)
    write_json_atomic(out_dir / CONFUSION, confusion)
    save_confusion(np.array(confusion["matrix"]), classes, out_dir / "confusion.png")
    real = (kth["data_root"] is not None) + (dvs_root is not None)  # KTH videos, event recordings
    return {
        "data/source": ("generated", "mixed", "real")[real],
        "data/synthetic": real < 2,
        "data/events": source_name,
        "data/fingerprint": fingerprint,
        "data/pretrain_fingerprint": pretrained["data/fingerprint"],
        "data/train_recordings": len(train_idx),
        "data/test_recordings": len(test_idx),
        "pretrain/eval/accuracy": pretrained["eval/accuracy"],
        "eval/zero_shot_accuracy": float((zero_shot == true).mean()),
        **scores,
    }
