"""DVS transfer (the paper's Appendix A): a ConvNet+RCN trained on KTH with EDR takes
event-camera frames straight in — no EDR layer — and is fine-tuned on 70 % of them.

Event recordings come from disk (``dvs_root``: ``<root>/<action>/<recording>``, any format
:mod:`edr.data.events` reads) or, by default, from the DVS simulator run on KTH videos
(``streams_per_class`` per action). Both are binned to one [ON, OFF] frame per video frame
interval, like EDR's output, and read and checked before the pre-training starts.
"""

from __future__ import annotations

import inspect
import logging
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn
from tqdm import tqdm

from edr.checks import interrupts
from edr.checks.config import (
    ConfigError,
    ExistingDir,
    NonNegativeInt,
    OpenFraction,
    PositiveFloat,
    PositiveInt,
    check_memory,
)
from edr.data.clips import VideoSource, resize_clip, take_frames
from edr.data.datasets import VideoSet, resolve_root
from edr.data.events import iter_recording, list_recordings, streamed_sensor
from edr.data.fingerprint import files_fingerprint
from edr.models.divergence import divergence
from edr.representations import EDR, DVSSimulator, events_to_frames
from edr.store.atomic import write_json_atomic
from edr.tasks.metrics import classification_metrics
from edr.tasks.plots import save_confusion
from edr.tasks.recognition import CONFUSION, Fitted, check_decoded_memory, check_resumable

log = logging.getLogger(__name__)
BIN_FRAMES = 16  # frame intervals binned at the sensor's resolution at a time
KTH_SETTINGS = ("videos", "synthetic", "data_root", "cache_dir", "resize", "max_frames", "frames",
                "crop")  # fmt: skip


def kth_settings(pretrain: Callable[..., Fitted]) -> dict[str, Any]:
    """The KTH data settings the pre-training reads (its config's, else its defaults): the
    simulator records the same videos, decoded, resized and cropped as the network saw them."""
    parameters = inspect.signature(pretrain).parameters
    return {name: parameters[name].default for name in KTH_SETTINGS}


def _bin_into(binned: np.ndarray, events: np.ndarray, begin: float, frame_us: float) -> None:
    """Add the [OFF, ON] counts of ``events`` (all inside) into ``binned`` (n, 2, H, W), whose n
    frame intervals of ``frame_us`` start at ``begin``."""
    height, width = binned.shape[2:]
    end = begin + (len(binned) + 1) * frame_us  # one interval past: rounding drops none of n
    counts = events_to_frames(
        events, height, width, time_window=frame_us, start_time=begin, end_time=end,
        dtype=np.float32,
    )  # fmt: skip
    binned += counts[: len(binned)]


def _event_clip(
    chunks: Iterable[np.ndarray],
    height: int,
    width: int,
    frame_us: float,
    frames: int,
    crop: int,
    start_us: int | None = 0,
) -> torch.Tensor:
    """Events, a chunk at a time in time order -> (frames, 2, crop, crop) float32: [ON, OFF]
    counts per frame interval from ``start_us`` (None: the first event's time). Only the first
    ``frames`` intervals are binned, BIN_FRAMES at a time at the sensor's resolution, each
    chunk added in as it comes: memory is a chunk's and the clip's, whatever the recording's
    length, density or sensor (a short one holds its last frame)."""
    parts: list[torch.Tensor] = []  # the groups of BIN_FRAMES intervals done, resized
    binned = np.zeros((min(BIN_FRAMES, frames), 2, height, width), np.float32)  # the next
    last = None  # the latest event's time
    for chunk in (c for c in chunks if len(c)):
        start_us = int(chunk["t"][0]) if start_us is None else start_us
        last = int(chunk["t"][-1])
        while len(chunk) and (first := len(parts) * BIN_FRAMES) < frames:
            begin, end = start_us + first * frame_us, start_us + (first + len(binned)) * frame_us
            t = chunk["t"]
            cut = int(np.searchsorted(t, end))
            if (early := int(np.searchsorted(t[:cut], begin))) < cut:  # none before start_us
                _bin_into(binned, chunk[early:cut], begin, frame_us)
            chunk = chunk[cut:]
            if len(chunk):  # later intervals: this group is whole
                parts.append(resize_clip(torch.from_numpy(binned[:, ::-1].copy()), crop))
                count = min(BIN_FRAMES, frames - first - len(binned))
                binned = np.zeros((max(count, 0), 2, height, width), np.float32)
    span = 1 if last is None or start_us is None else last - start_us + 1
    n_bins = max(1, min(frames, int(np.ceil(span / frame_us))))
    if len(parts) * BIN_FRAMES < n_bins:  # the group the last event is in, as far as it
        kept = binned[: n_bins - len(parts) * BIN_FRAMES, ::-1]  # tonic's [OFF, ON] -> [ON, OFF]
        parts.append(resize_clip(torch.from_numpy(kept.copy()), crop))
    return take_frames(torch.cat(parts), 0, frames)


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
def _predict(backbone: nn.Module, clips: torch.Tensor, true: np.ndarray, batch: int = 8
              ) -> tuple[np.ndarray, float]:  # fmt: skip
    """(the class each clip is given, the accuracy: NaN where a logit is not a number)."""
    backbone.eval()
    logits = torch.cat([backbone(clips[i : i + batch]) for i in range(0, len(clips), batch)])
    predicted = logits.argmax(-1).numpy()
    finite = bool(torch.isfinite(logits).all())
    return predicted, float((predicted == true).mean()) if finite else float("nan")


def _simulator(
    simulator: dict[str, float] | None, dvs_root: str | None, train_fraction: float,
    streams_per_class: int,
) -> DVSSimulator:  # fmt: skip
    """The DVS simulator of these settings; one line for settings that cannot work, before any
    work."""
    try:
        sim = DVSSimulator(**(simulator or {}))
    except (TypeError, ValueError) as error:
        raise ConfigError(f"task.simulator: {error}") from None
    if not dvs_root and round(train_fraction * streams_per_class) in (0, streams_per_class):
        raise ConfigError(
            f"task.train_fraction={train_fraction} of task.streams_per_class="
            f"{streams_per_class} leaves no recording of a class to "
            f"{'fine-tune on' if train_fraction < 0.5 else 'test'}: raise streams_per_class"
        )
    return sim


def _pretrained(
    pretrain: Callable[..., Fitted], out_dir: Path, seed: int, resume: bool
) -> tuple[nn.Module, dict[str, Any]]:
    """The ConvNet+RCN trained on KTH with EDR (in ``out_dir``), its backbone and metrics."""
    out_dir.mkdir(parents=True, exist_ok=True)
    model, pretrained = pretrain(out_dir=out_dir, seed=seed, resume=resume)
    edr = model.representation
    if not isinstance(edr, EDR) or edr.out_channels(1) != 2:
        raise ValueError(
            "DVS transfer needs a network trained on EDR with one ON/OFF pair per pixel "
            "(representation=edr with color gray or gray video, one timescale or combine=sum)"
        )
    return model.backbone, pretrained


def _recorded_clips(
    dvs_root: str, classes: list[str], sim: DVSSimulator, frames: int, crop: int
) -> tuple[list[torch.Tensor], list[int], str]:
    """Each recording under ``dvs_root`` (class/recording) as a clip of ``frames`` [ON, OFF]
    frames (read only as far as that needs); their labels and the files' fingerprint."""
    recordings = list_recordings(dvs_root, classes)
    fingerprint = files_fingerprint([p for p, _ in recordings], Path(dvs_root))
    clips, labels = [], []
    duration = frames * sim.frame_us  # what is used: decoding stops there
    for path, label in tqdm(recordings, desc="reading recordings", unit="file"):
        h, w = streamed_sensor(path, duration)
        check_memory(
            f"task.dvs_root={dvs_root}",
            f"{path}'s frames binned {BIN_FRAMES} at a time at its {w}x{h} sensor",
            2 * min(BIN_FRAMES, frames) * 2 * h * w * 4,  # the counts and one chunk's, float32
        )  # fmt: skip
        chunks = iter_recording(path, duration)  # bounded, however dense the recording
        clips.append(_event_clip(chunks, h, w, sim.frame_us, frames, crop, start_us=None))
        labels.append(label)
    return clips, labels, fingerprint


def _simulated_clips(
    pool: list[Any], frame_source: VideoSource, num_classes: int, per_class: int,
    sim: DVSSimulator, frames: int, crop: int,
) -> tuple[list[torch.Tensor], list[int]]:  # fmt: skip
    """The first ``per_class`` videos of each class in ``pool`` recorded by the DVS simulator,
    as clips of [ON, OFF] frames; their labels."""
    chosen = [
        v for label in range(num_classes) for v in [u for u in pool if u.label == label][:per_class]
    ]
    clips, labels = [], []
    for video in tqdm(chosen, desc="simulating DVS", unit="video"):
        gray = np.asarray(frame_source(video.path))[:, 0]  # (T, H, W)
        h, w = gray.shape[1:]
        clips.append(_event_clip([sim.simulate(gray)], h, w, sim.frame_us, frames, crop))
        labels.append(video.label)
    return clips, labels


def _finetune(
    backbone: nn.Module, optimizer: Callable[..., torch.optim.Optimizer], train_x: torch.Tensor,
    train_y: torch.Tensor, epochs: int, batch_size: int,
) -> dict[str, Any]:  # fmt: skip
    """Fine-tune ``backbone`` on the event clips ``train_x`` (N, T, 2, crop, crop); where it
    diverged, if it did (recorded as recognition records it, not a crash)."""
    opt = optimizer(backbone.parameters())
    loss_fn = nn.CrossEntropyLoss()
    step = 0
    for epoch in (bar := tqdm(range(epochs), desc="fine-tuning", unit="epoch")):
        backbone.train()
        order = torch.randperm(len(train_x))
        for i in range(0, len(order), batch_size):
            interrupts.raise_if_stopping()
            batch, step = order[i : i + batch_size], step + 1
            loss = loss_fn(backbone(train_x[batch]), train_y[batch])
            reason = divergence(backbone, loss)
            if reason is None:
                opt.zero_grad(set_to_none=True)
                loss.backward()
                opt.step()
                reason = divergence(backbone)
            if reason is not None:
                log.warning("fine-tuning diverged at step %d (%s): recorded as diverged",
                            step, reason)  # fmt: skip
                return {"train/diverged_epoch": epoch + 1, "train/diverged_step": step,
                        "train/diverged_reason": reason}  # fmt: skip
        bar.set_postfix(loss=f"{loss.item():.3f}")
    return {}


def dvs_transfer(
    *,
    out_dir: Path,
    seed: int,
    pretrain: Callable[..., Fitted],
    optimizer: Callable[..., torch.optim.Optimizer],
    dvs_root: ExistingDir | None = None,
    simulator: dict[str, float] | None = None,
    streams_per_class: PositiveInt = 10,
    train_fraction: OpenFraction = 0.7,
    finetune_epochs: NonNegativeInt = 20,
    batch_size: PositiveInt = 8,
    event_scale: PositiveFloat = 1.0,
    resume: bool = False,
) -> dict[str, Any]:
    """Pre-train on KTH with EDR, then fine-tune and test on event-camera frames; returns metrics.

    The KTH videos the simulator records, and their frames and crop, are the pre-training's
    (``pretrain``'s settings). ``resume`` continues the pre-training from its checkpoint; fine-tuning is short and reruns.
    """
    sim = _simulator(simulator, dvs_root, train_fraction, streams_per_class)

    # ---- 1. event recordings, as [ON, OFF] frames: checked before any training -------------
    kth = kth_settings(pretrain)
    videos: Callable[..., VideoSet] = kth["videos"]
    frames, crop, cache_dir = kth["frames"], kth["crop"], kth["cache_dir"]
    check_decoded_memory(kth["resize"], frames, 1, "task.pretrain")  # the simulator's, gray
    root = resolve_root(kth["data_root"], kth["synthetic"], cache_dir, "task.pretrain")
    classes = videos(root, train=True).classes
    if dvs_root:
        source_name = f"recordings under {dvs_root}"
        clips, labels, fingerprint = _recorded_clips(dvs_root, classes, sim, frames, crop)
    else:
        source_name = f"DVS simulator on {streams_per_class} videos per class of {root}"
        fingerprint = None  # the pre-training's videos: known once it has run
        frame_source = VideoSource(
            cache_dir, size=tuple(kth["resize"]), gray=True, max_frames=kth["max_frames"]
        )
        pool = [v for split in (True, False) for v in videos(root, train=split).videos]
        clips, labels = _simulated_clips(
            pool, frame_source, len(classes), streams_per_class, sim, frames, crop
        )
    clips_t = torch.stack(clips) * event_scale  # (N, frames, 2, crop, crop)
    labels_np = np.array(labels)
    train_idx, test_idx = _split(labels_np, train_fraction, seed)
    if len(train_idx) == 0 or len(test_idx) == 0:
        raise ConfigError(
            f"{len(labels_np)} recordings are too few for a {train_fraction:.0%} split"
        )

    # ---- 2. the ConvNet+RCN trained on KTH with EDR ------------------------------------------
    backbone, pretrained = _pretrained(pretrain, out_dir / "pretrain", seed, resume)
    fingerprint = fingerprint or pretrained["data/fingerprint"]

    # ---- 3. straight in, then fine-tuned ------------------------------------------------------
    true = labels_np[test_idx]
    _, zero_shot = _predict(backbone, clips_t[test_idx], true)
    train_x, train_y = clips_t[train_idx], torch.from_numpy(labels_np[train_idx])
    diverged = _finetune(backbone, optimizer, train_x, train_y, finetune_epochs, batch_size)
    predicted, accuracy = _predict(backbone, clips_t[test_idx], true)
    scores, confusion = classification_metrics(predicted, true, classes)
    if diverged or np.isnan(accuracy):  # what a network of NaNs predicts is no accuracy
        scores["eval/accuracy"] = float("nan")
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
        **{f"pretrain/{k}": v for k, v in pretrained.items() if "diverged" in k},
        "eval/zero_shot_accuracy": zero_shot,
        **scores,
        **diverged,
    }


def _check_pretraining(out_dir: Path, *, pretrain: Callable[..., Fitted], **_: Any) -> None:
    """The pre-training's checkpoint a resumed run would continue from, checked as a KTH run's
    (:func:`edr.tasks.recognition.check_resumable`) before edr-run rewrites the record."""
    check_resumable(out_dir / "pretrain", **pretrain.keywords)


dvs_transfer.check_resumable = _check_pretraining  # type: ignore[attr-defined]  # edr-run calls it
