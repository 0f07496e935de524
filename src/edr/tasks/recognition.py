"""Video recognition (the paper's Tables 2 and 4): train a representation x backbone, test it.

One function, top to bottom: data, model, optimizer; the epoch loop with a checkpoint after
every epoch (``resume=true`` continues from the run directory's last one); then the final
10-crop video accuracy, per-class accuracy, confusion matrix, learning curve and activation
sparsity per layer.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn
from torch.utils.data import DataLoader, RandomSampler
from tqdm import tqdm

from edr.data.clips import PAPER_SCALES, ClipDataset, PrecomputedSource, VideoSource
from edr.data.datasets import VideoSet
from edr.models import RecognitionModel, activation_sparsity
from edr.representations import Representation
from edr.tasks.checkpoints import CHECKPOINT, load_checkpoint, save_atomic, save_checkpoint
from edr.tasks.plots import save_confusion, save_learning_curve

MODEL = "model.pt"  # the trained RecognitionModel, whole (torch.save), for later tasks


def dataset_root(
    data_root: str | None, synthetic: Callable[..., Path], cache_dir: str | Path
) -> Path:
    """``data_root`` when given; else the generated data set ``synthetic`` writes (once) in the cache."""
    if data_root:
        return Path(data_root)
    settings = json.dumps({"fn": synthetic.func.__name__, **synthetic.keywords}, sort_keys=True)
    root = (
        Path(cache_dir)
        / f"{synthetic.func.__name__}_{hashlib.sha1(settings.encode()).hexdigest()[:10]}"
    )
    if not root.exists():
        print(f"no data.root given: generating a synthetic data set in {root}")
    return synthetic(root)


@torch.no_grad()
def evaluate(
    model: nn.Module, dataset: ClipDataset, device: torch.device, batch_videos: int = 4
) -> tuple[np.ndarray, np.ndarray]:
    """(predicted, true) labels per video: argmax of the softmax averaged over its 10 crops."""
    model.eval()
    predicted, true = [], []
    for crops, labels in tqdm(
        DataLoader(dataset, batch_size=batch_videos), desc="test", unit="batch", leave=False
    ):
        b, n = crops.shape[:2]
        logits = model(crops.flatten(0, 1).to(device))  # (B*10, classes)
        scores = logits.softmax(-1).view(b, n, -1).mean(1)
        predicted.append(scores.argmax(-1).cpu().numpy())
        true.append(labels.numpy())
    return np.concatenate(predicted), np.concatenate(true)


def confusion_matrix(predicted: np.ndarray, true: np.ndarray, classes: int) -> np.ndarray:
    """(classes, classes) counts, rows = true class, columns = predicted class."""
    matrix = np.zeros((classes, classes), np.int64)
    np.add.at(matrix, (true, predicted), 1)
    return matrix


def train_recognition(
    *,
    out_dir: Path,
    seed: int,
    representation: Representation,
    backbone: Callable[..., nn.Module],
    optimizer: Callable[..., torch.optim.Optimizer],
    videos: Callable[..., VideoSet],
    synthetic: Callable[..., Path],
    data_root: str | None = None,
    cache_dir: str = "results/cache",
    resize: Sequence[int] = (89, 67),
    gray: bool = False,
    max_frames: int | None = None,
    frames: int = 60,
    crop: int = 58,
    scales: Sequence[float] = PAPER_SCALES,
    epochs: int = 26,
    clips_per_epoch: int = 9000,
    batch_size: int = 15,
    milestones: Sequence[int] = (13, 24),
    gamma: float = 0.1,
    eval_every: int = 1,
    resume: bool = False,
    logger: str = "csv",
    device: str = "auto",
    num_workers: int = 0,
) -> dict[str, Any]:
    """Train ``backbone`` on ``representation`` of the videos, test with 10 crops; returns metrics."""
    # ---- data --------------------------------------------------------------------------------
    if device == "auto":
        device = "cuda" if torch.cuda.is_available() else "cpu"
    dev = torch.device(device)
    root = dataset_root(data_root, synthetic, cache_dir)
    train_videos, test_videos = videos(root, train=True), videos(root, train=False)
    classes = train_videos.classes
    frame_source = VideoSource(cache_dir, size=tuple(resize), gray=gray, max_frames=max_frames)
    if representation.precompute:  # computed once per video, like the paper's flows
        source: Callable = PrecomputedSource(frame_source, representation, cache_dir)
        online, negate, clip_frames = None, representation.hflip_negate, frames
    else:
        source, online, negate = frame_source, representation, ()
        clip_frames = representation.out_frames(frames)
    paths = [v.path for v in train_videos.videos + test_videos.videos]
    frame_source.cache.fill(paths, frame_source.decode, desc="decoding")
    if online is None:
        source.cache.fill(
            paths, source.compute, desc=f"precomputing {type(representation).__name__}"
        )
    train_set = ClipDataset(
        train_videos, source, frames=frames, crop=crop, train=True, scales=scales, negate=negate
    )
    test_set = ClipDataset(
        test_videos, source, frames=frames, crop=crop, train=False, negate=negate
    )

    # ---- model, optimizer, logger ------------------------------------------------------------
    in_channels = representation.out_channels(frame_source.channels)
    net = backbone(
        in_channels=in_channels,
        num_classes=len(classes),
        frames=clip_frames,
        height=crop,
        width=crop,
    )
    model = RecognitionModel(online, net).to(dev)
    opt = optimizer(model.parameters())
    scheduler = torch.optim.lr_scheduler.MultiStepLR(opt, milestones=list(milestones), gamma=gamma)
    from torchrl.record.loggers import get_logger  # heavy import, only where it is used

    log = get_logger(logger, logger_name=str(out_dir), experiment_name="logs") if logger else None
    history: list[dict[str, float]] = []
    start_epoch = 0
    checkpoint = out_dir / CHECKPOINT
    parts = {"model": model, "optimizer": opt, "scheduler": scheduler}
    if resume and checkpoint.is_file():
        state = load_checkpoint(checkpoint, parts)
        history, start_epoch = state["history"], state["epoch"]
    loss_fn = nn.CrossEntropyLoss()

    # ---- training ----------------------------------------------------------------------------
    for epoch in range(start_epoch, epochs):
        model.train()
        sampler = RandomSampler(train_set, replacement=True, num_samples=clips_per_epoch)
        loader = DataLoader(
            train_set, batch_size=batch_size, sampler=sampler, num_workers=num_workers
        )
        total, correct, loss_sum = 0, 0, 0.0
        bar = tqdm(loader, desc=f"epoch {epoch + 1}/{epochs}", unit="batch")
        for clips, labels in bar:
            clips, labels = clips.to(dev), labels.to(dev)
            logits = model(clips)
            loss = loss_fn(logits, labels)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            total += len(labels)
            correct += int((logits.argmax(-1) == labels).sum())
            loss_sum += loss.item() * len(labels)
            bar.set_postfix(loss=f"{loss_sum / total:.3f}", acc=f"{correct / total:.2f}")
        if not np.isfinite(loss_sum):
            raise FloatingPointError(f"training loss is {loss_sum} at epoch {epoch + 1}")
        row = {
            "epoch": epoch + 1,
            "train/loss": loss_sum / total,
            "train/accuracy": correct / total,
        }
        row["train/lr"] = opt.param_groups[0]["lr"]
        scheduler.step()
        if (epoch + 1) % eval_every == 0 or epoch + 1 == epochs:
            predicted, true = evaluate(model, test_set, dev)
            row["eval/accuracy"] = float((predicted == true).mean())
        history.append(row)
        if log is not None:
            for key, value in row.items():
                if key != "epoch":
                    log.log_scalar(key, value, step=epoch + 1)
        save_checkpoint(checkpoint, parts, history=history, epoch=epoch + 1)

    # ---- final evaluation --------------------------------------------------------------------
    predicted, true = evaluate(model, test_set, dev)
    matrix = confusion_matrix(predicted, true, len(classes))
    per_class = matrix.diagonal() / np.maximum(matrix.sum(1), 1)
    probe = torch.stack([train_set[i][0] for i in range(min(4, len(train_set)))]).to(dev)
    model.eval()
    sparsity = activation_sparsity(model, probe)
    save_atomic(model.cpu(), out_dir / MODEL)
    save_learning_curve(history, out_dir / "learning_curve.png")
    save_confusion(matrix, classes, out_dir / "confusion.png")
    metrics: dict[str, Any] = {
        "data/root": str(root),
        "data/synthetic": data_root is None,
        "data/train_videos": len(train_videos),
        "data/test_videos": len(test_videos),
        "eval/accuracy": float((predicted == true).mean()),
        "eval/chance": 1.0 / len(classes),
        "train/loss": history[-1]["train/loss"] if history else float("nan"),
        "model/parameters": sum(p.numel() for p in model.parameters()),
        **{f"eval/per_class/{c}": float(a) for c, a in zip(classes, per_class, strict=True)},
        **{f"sparsity/{name}": value for name, value in sparsity.items()},
        "eval/confusion": matrix.tolist(),
        "history": history,
    }
    return metrics
