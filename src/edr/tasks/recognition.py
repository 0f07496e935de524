"""Video recognition (the paper's Tables 2 and 4): train a representation x backbone, test it.

One function, top to bottom: data, model, optimizer; the epoch loop with a checkpoint after
every epoch (``resume=True`` continues from the run directory's last one); then the final
10-crop video accuracy, per-class accuracy, confusion matrix, learning curve and activation
sparsity per layer. ``fit_recognition`` also returns the trained model (DVS transfer keeps
it); ``train_recognition``, the tasks' entry, returns the metrics only.
"""

from __future__ import annotations

import functools
import inspect
import json
import logging
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Annotated, Any, Literal, NamedTuple

import numpy as np
import torch
from hydra.utils import instantiate
from torch import nn
from torch.utils.data import DataLoader, RandomSampler
from tqdm import tqdm

from edr.checks import interrupts
from edr.checks.config import (
    ConfigError,
    DataRoot,
    Device,
    Fraction,
    NonEmpty,
    NonNegativeInt,
    OutputDir,
    PositiveFloat,
    PositiveInt,
    check_memory,
    torch_device,
)
from edr.data.clips import (
    FRAME_ORDER,
    PAPER_SCALES,
    ClipDataset,
    FrameControl,
    PrecomputedSource,
    VideoSource,
)
from edr.data.datasets import Video, VideoSet, folds_problem, resolve_root, videos_fingerprint
from edr.models import RecognitionModel, activation_sparsity, input_norm
from edr.models.dead_units import DeadUnits
from edr.models.divergence import divergence
from edr.representations import EDR, Representation
from edr.representations.base import check_enough_frames
from edr.store.atomic import write_json_atomic
from edr.store.checkpoints import (
    CHECKPOINT,
    DATA_FINGERPRINT,
    START_OVER,
    check_same_data,
    load_checkpoint,
    restore,
    save_atomic,
    save_checkpoint,
)
from edr.store.records import RECORD_NAME
from edr.tasks.metrics import classification_metrics
from edr.tasks.plots import save_confusion, save_learning_curve
from edr.tasks.predictions import (
    PREDICTIONS,
    video_accuracy,
    video_predictions,
    write_predictions,
)
from edr.tasks.rebuild import instantiate_from_record
from edr.tasks.run_folder import (
    Reader,
    RefusedFolder,
    check_weights,
    config_node,
    open_record,
    payload_part,
)
from edr.tasks.scalars import LoggerName, open_logger
from edr.tasks.seeds import seed_everything

log = logging.getLogger(__name__)

MODEL = "model.pt"  # the trained model's state_dict and the backbone's size arguments
HISTORY = "history.json"  # one row per epoch: train loss and accuracy, test accuracy, lr
CONFUSION = "confusion.json"  # the final confusion matrix with its class names
FOLD_METRICS = "fold.json"  # a finished fold's metrics, in fold<k>/ (a split by person)


class Fitted(NamedTuple):
    model: RecognitionModel
    metrics: dict[str, Any]


class Tested(NamedTuple):
    scores: np.ndarray  # (items, classes): each test item's softmax averaged over its 10 crops
    true: np.ndarray  # (items,) class indices

    @property
    def predicted(self) -> np.ndarray:
        """(items,) each item's predicted class."""
        return self.scores.argmax(-1)


@torch.no_grad()
def evaluate(
    model: nn.Module, dataset: ClipDataset, device: torch.device, batch_videos: int = 4
) -> Tested:
    """Class scores and true labels per test item, in ``dataset.items``'s order: the softmax
    averaged over its 10 crops."""
    model.eval()
    scores, true = [], []
    for crops, labels in tqdm(
        DataLoader(dataset, batch_size=batch_videos), desc="test", unit="batch", leave=False
    ):
        interrupts.raise_if_stopping()
        b, n = crops.shape[:2]
        logits = model(crops.flatten(0, 1).to(device))  # (B*10, classes)
        scores.append(logits.softmax(-1).view(b, n, -1).mean(1).cpu().numpy())  # (B, classes)
        true.append(labels.numpy())
    return Tested(np.concatenate(scores), np.concatenate(true))


# Who loads a recognition run's model, for what its refusals say (edr.tasks.run_folder).
LOADER = Reader(
    name="load_model", verb="load", tasks=("kth", "ucf101"),
    elsewhere="load an Atari run's network with edr.tasks.atari.load_network, or score it with "
    "edr-eval",
    remedy="load a run folder edr-run wrote, or a copy of it whose files are whole",
)  # fmt: skip


def load_model(run_dir: str | Path) -> RecognitionModel:
    """The model a recognition run trained, rebuilt from its record's config and ``model.pt``.
    The folder is checked first, as edr-eval checks the folder it scores
    (:mod:`edr.tasks.run_folder`): no live run holds it, its record is a recognition run's
    as edr-run writes it, the config builds only the suite's own parts
    (:mod:`edr.tasks.rebuild`), and ``model.pt`` holds what edr-run writes, the weights of the
    model it rebuilds. Each refusal is one line naming the file; nothing is written."""
    run_dir = Path(run_dir)
    record = open_record(run_dir, LOADER)
    nodes = {k: config_node(run_dir / RECORD_NAME, record, k, LOADER)
             for k in ("representation", "backbone")}  # fmt: skip
    path = run_dir / MODEL
    saved = load_checkpoint(path, remedy=LOADER.remedy)
    part = functools.partial(payload_part, path, saved, remedy=LOADER.file_remedy)
    weights, arguments = part("state_dict", dict), part("backbone_args", dict)
    representation = None
    if part("online", bool):  # a representation computed in the model, with weights of its own
        representation = instantiate_from_record(nodes["representation"], "config.representation")
    backbone = instantiate_from_record(nodes["backbone"], "config.backbone")
    try:
        backbone = backbone(**arguments)
    except (TypeError, ValueError) as error:  # arguments no backbone takes
        raise RefusedFolder(
            f"{path}: backbone_args={arguments!r} do not build config.backbone ({error}): "
            f"{LOADER.file_remedy}"
        ) from None
    norm = input_norm(arguments["in_channels"]) if saved.get("input_norm") else None
    model = RecognitionModel(representation, backbone, norm)
    check_weights(path, weights, model.state_dict(), LOADER.file_remedy)
    model.load_state_dict(weights)
    return model


# What a checkpoint of fit_recognition holds that a resume reads (the training's parts, its rows).
CHECKPOINT_PARTS = {"model": dict, "optimizer": dict, "scheduler": dict, "rng": dict,
                    "history": list}  # fmt: skip


def check_resumable(out_dir: Path, **settings: Any) -> None:
    """The checkpoints a resumed run would continue from (its own; in a split by person, each
    unfinished fold's), checked before edr-run rewrites the run's record, as ``load_model``
    checks ``model.pt``: readable, holding what fit_recognition writes, the model's keys and
    shapes those of the model ``settings`` (fit_recognition's) build (:func:`_fresh_model`:
    nothing decoded). One line naming the file otherwise, with edr-run's remedy; the folder
    stays as it was."""
    candidates = [out_dir / CHECKPOINT, *sorted(out_dir.glob(f"fold*/{CHECKPOINT}"))]
    paths = [p for p in candidates if p.is_file() and not _fold_done(p.parent)]
    weights: dict[Path, Any] = {}  # each file's model, once it holds what fit_recognition writes
    for path in paths:
        state = load_checkpoint(path)
        for key, kind in CHECKPOINT_PARTS.items():
            payload_part(path, state, key, kind, START_OVER)
        weights[path] = state["model"]
    if weights:  # the model built only now: a file of something else is refused before
        expected = _fresh_model(settings).state_dict()
        for path, found in weights.items():
            check_weights(path, found, expected, START_OVER)


def _fresh_model(settings: dict[str, Any]) -> RecognitionModel:
    """The model fit_recognition builds from ``settings`` (its arguments, each missing one at
    its default), on the CPU and a fork of torch's generator (the run's own draws stay as they
    were); the data set's classes listed, no video decoded."""
    parameters = inspect.signature(functools.partial(fit_recognition, **settings)).parameters
    given = {name: parameter.default for name, parameter in parameters.items()}
    representation: Representation = given["representation"]
    root = resolve_root(given["data_root"], given["synthetic"], given["cache_dir"])
    classes = given["videos"](root, train=True).classes
    online = None if representation.precompute else representation
    frames = _backbone_frames(representation, given["frames"])
    in_channels = representation.out_channels(1 if given["gray"] else 3)
    with torch.random.fork_rng():
        model, _ = _model(given["backbone"], online, in_channels, len(classes), frames,
                          given["crop"], given["normalize_input"], torch.device("cpu"))  # fmt: skip
    return model


def _fold_done(fold_dir: Path) -> bool:
    """Whether a fold of a split by person finished (its metrics and predictions written): a
    resumed run does not train it again."""
    return (fold_dir / FOLD_METRICS).is_file() and (fold_dir / PREDICTIONS).is_file()


def fit_recognition(
    *,
    out_dir: Path,
    seed: int,
    representation: Representation,
    backbone: Callable[..., nn.Module],
    optimizer: Callable[..., torch.optim.Optimizer],
    videos: Callable[..., VideoSet],
    synthetic: Callable[..., Path],
    data_root: DataRoot | None = None,
    cache_dir: OutputDir = "results/cache",
    resize: tuple[PositiveInt, PositiveInt] = (89, 67),
    gray: bool = False,
    max_frames: PositiveInt | None = None,
    frames: PositiveInt = 60,
    crop: PositiveInt = 58,
    scales: Annotated[Sequence[Fraction], NonEmpty] = PAPER_SCALES,  # of the short side
    epochs: PositiveInt = 26,
    clips_per_epoch: PositiveInt = 9000,
    batch_size: PositiveInt = 15,
    milestones: Sequence[PositiveInt] = (13, 24),
    gamma: PositiveFloat = 0.1,
    eval_every: PositiveInt = 1,
    shuffle_frames: bool = False,
    frame_control: Literal["one_frame", "shuffled_in_video"] | None = None,
    normalize_input: bool = True,
    resume: bool = False,
    logger: LoggerName = "csv",
    device: Device = "auto",
    num_workers: NonNegativeInt = 0,
) -> Fitted:
    """Train ``backbone`` on ``representation`` of the videos, test with 10 crops; returns the
    model and the metrics, and writes the history, confusion matrix, per-video predictions,
    figures and model. The controls ``shuffle_frames`` (within each clip: motion statistics
    survive) and ``frame_control`` (``one_frame``: appearance alone; ``shuffled_in_video``) are
    :func:`_frame_control`'s; ``normalize_input`` standardises each input channel."""
    _check_sizes(crop, resize, frames, batch_size, 1 if gray else 3, representation)
    _check_backbone_takes(backbone, representation, 1 if gray else 3, frames, crop)
    dev = torch_device(device)
    data = _Data.find(data_root, synthetic, cache_dir, videos)
    control = _frame_control(shuffle_frames, frame_control, representation, data.test)
    checkpoint = out_dir / CHECKPOINT
    state = load_checkpoint(checkpoint) if resume else None
    if state is not None:  # a checkpoint goes on only on the data it trained on
        check_same_data(state, data.fingerprint, checkpoint)
    frame_source = VideoSource(cache_dir, size=tuple(resize), gray=gray, max_frames=max_frames)
    online, train_set, test_set, clip_frames = _clip_sets(
        representation, frame_source, cache_dir, data, frames, crop, scales, control
    )

    # ---- model, optimizer --------------------------------------------------------------------
    in_channels = representation.out_channels(frame_source.channels)
    model, rebuild = _model(backbone, online, in_channels, len(data.classes), clip_frames, crop,
                            normalize_input, dev)  # fmt: skip
    opt = optimizer(model.parameters())
    scheduler = torch.optim.lr_scheduler.MultiStepLR(opt, milestones=list(milestones), gamma=gamma)
    parts = {"model": model, "optimizer": opt, "scheduler": scheduler}
    history: list[dict[str, float]] = state["history"] if state else []  # a row per epoch
    if state is not None:
        restore(state, parts)

    # ---- training ----------------------------------------------------------------------------
    def save() -> None:
        save_checkpoint(checkpoint, parts, history=history, epoch=len(history),
                        **{DATA_FINGERPRINT: data.fingerprint})  # fmt: skip

    loader = functools.partial(_epoch_loader, train_set, clips_per_epoch, batch_size, num_workers)
    scalars = open_logger(logger, out_dir, step=len(history))
    diverged, tested = _epochs(
        model, opt, scheduler, loader, test_set, dev, history, epochs, eval_every, scalars, save
    )

    # ---- final evaluation --------------------------------------------------------------------
    metrics = _finish(
        out_dir, model, train_set, test_set, dev, history, data.classes, rebuild, tested
    )
    if diverged:  # what a network of NaNs predicts is no accuracy
        metrics.update(dict.fromkeys(_ACCURACIES, float("nan")))
    data_part = data.metrics(data_root, synthetic, test_set, control)
    return Fitted(model, {**data_part, **metrics, **diverged})


_ACCURACIES = ("eval/accuracy", "eval/item_accuracy", "eval/video_accuracy")


def _frame_control(
    shuffle_frames: bool, frame_control: str | None, representation: Representation,
    test: VideoSet,
) -> FrameControl | None:  # fmt: skip
    """The control the clips get (None: frames in order); one line for a pair that makes no
    sense: two controls at once, a control of the frames under a representation computed
    beforehand on them in order (its cache), a whole-video shuffle of videos split in time."""
    if shuffle_frames and frame_control is not None:
        raise ConfigError(
            f"task.shuffle_frames=true with task.frame_control={frame_control}: one control of "
            "the frames at a time; set task.shuffle_frames=false or task.frame_control=null"
        )
    if frame_control is not None and representation.precompute:
        raise ConfigError(
            f"task.frame_control={frame_control} with {type(representation).__name__}, computed "
            "once on each video's frames in order (its cache): the control would reach only its "
            "output; use an on-the-fly representation (fdr, edr, graydiff, rgbdiff)"
        )
    if frame_control == "shuffled_in_video" and test.time_split is not None:
        raise ConfigError(
            "task.frame_control=shuffled_in_video with videos split in time: a whole-video "
            "shuffle would carry test frames into the training part; use task.frame_control="
            "one_frame or task.shuffle_frames=true, or split the videos by person"
        )
    return "shuffled_in_clip" if shuffle_frames else frame_control


def _model(
    backbone: Callable[..., nn.Module],
    online: Representation | None,
    in_channels: int,
    num_classes: int,
    frames: int,
    crop: int,
    normalize_input: bool,
    device: torch.device,
) -> tuple[RecognitionModel, dict[str, Any]]:
    """The backbone on ``in_channels`` x ``frames`` x ``crop`` x ``crop`` clips, behind the
    on-the-fly representation if any, on ``device``; and what a record keeps to rebuild it."""
    backbone_args = {"in_channels": in_channels, "num_classes": num_classes, "frames": frames,
                     "height": crop, "width": crop}  # fmt: skip
    norm = input_norm(in_channels) if normalize_input else None
    model = RecognitionModel(online, backbone(**backbone_args), norm).to(device)
    rebuild = {"online": online is not None, "input_norm": normalize_input,
               "backbone_args": backbone_args}  # fmt: skip
    return model, rebuild


def _epoch_loader(
    train_set: ClipDataset, clips_per_epoch: int, batch_size: int, num_workers: int
) -> DataLoader:
    """An epoch: ``clips_per_epoch`` training clips drawn with replacement."""
    sampler = RandomSampler(train_set, replacement=True, num_samples=clips_per_epoch)
    return DataLoader(train_set, batch_size=batch_size, sampler=sampler, num_workers=num_workers)


class _Data(NamedTuple):
    """A run's videos: where they are, the training and test splits, their fingerprint."""

    root: Path
    train: VideoSet
    test: VideoSet
    fingerprint: str

    @classmethod
    def find(
        cls, data_root: str | None, synthetic: Callable[..., Path], cache_dir: str,
        videos: Callable[..., VideoSet],
    ) -> _Data:  # fmt: skip
        """The videos under ``data_root`` (generated into ``cache_dir`` without one); one line
        for a class with no training video."""
        root = resolve_root(data_root, synthetic, cache_dir)
        train, test = videos(root, train=True), videos(root, train=False)
        _check_every_class_trains(root, train)
        return cls(root, train, test, videos_fingerprint(root, [train, test]))

    @property
    def classes(self) -> list[str]:
        return self.train.classes

    @property
    def videos(self) -> tuple[Video, ...]:
        """Every video of the two splits (a video split in time is in both)."""
        return self.train.videos + self.test.videos

    def metrics(
        self, data_root: str | None, synthetic: Callable[..., Path], test_set: ClipDataset,
        control: FrameControl | None,
    ) -> dict[str, Any]:  # fmt: skip
        """The record's ``data/`` part: what the videos were and how they were cut."""
        return {
            **data_labels(data_root, synthetic, self.train, len({v.path for v in self.videos})),
            "data/synthetic": data_root is None,
            "data/root": str(self.root),
            "data/fingerprint": self.fingerprint,
            "data/train_videos": len(self.train),
            "data/test_videos": len(self.test),
            # test items: one per video, unless split in time or into sub-sequences
            "data/test_clips": len(test_set),
            "data/frame_order": FRAME_ORDER[control],
        }


def _epochs(
    model: RecognitionModel, opt: torch.optim.Optimizer, scheduler: Any,
    loader: Callable[[], DataLoader], test_set: ClipDataset, dev: torch.device,
    history: list[dict[str, float]], epochs: int, eval_every: int, scalars: Any,
    save: Callable[[], None],
) -> _Trained:  # fmt: skip
    """Train from epoch ``len(history)`` to ``epochs``, a row of ``history`` and a checkpoint
    per epoch; where the training diverged if it did, and the last epoch's test predictions."""
    dead_units = DeadUnits(model)  # whether the network stays alive, per epoch
    online = model.representation
    tested = None
    for epoch in range(len(history), epochs):
        dead_units.reset()
        row, diverged = _train_epoch(model, opt, loader(), dev, epoch, epochs)
        if diverged:
            log.warning(
                "training diverged at epoch %d, step %d (%s): it stops here and the run is "
                "recorded as diverged",
                epoch + 1, diverged["train/diverged_step"], diverged["train/diverged_reason"],
            )  # fmt: skip
            return _Trained(diverged, None)
        row.update(dead_units.fractions())  # units that fired on no training clip of the epoch
        row.update(_learned(online))  # a learnable EDR's half-lives, betas and nus, by epoch
        row["train/lr"] = opt.param_groups[0]["lr"]
        scheduler.step()
        if (epoch + 1) % eval_every == 0 or epoch + 1 == epochs:
            tested = evaluate(model, test_set, dev)
            row["eval/accuracy"] = float((tested.predicted == tested.true).mean())
        history.append(row)
        if scalars is not None:
            for key, value in row.items():
                if key != "epoch":
                    scalars.log_scalar(key, value, step=epoch + 1)
        save()
    return _Trained({}, tested)


class _Trained(NamedTuple):
    diverged: dict[str, Any]  # where the training diverged (empty if it did not)
    # the final epoch's test, if this call ran it (the model is unchanged since)
    tested: Tested | None


def _finish(
    out_dir: Path, model: RecognitionModel, train_set: ClipDataset, test_set: ClipDataset,
    dev: torch.device, history: list[dict[str, float]], classes: list[str],
    rebuild: dict[str, Any], tested: Tested | None,
) -> dict[str, Any]:  # fmt: skip
    """The final test with 10 crops (``tested``, the last epoch's, when given), the activations'
    sparsity on a few training clips, and the files a run leaves (``model.pt`` with
    ``rebuild``, history, confusion, per-video predictions, figures); the record's test,
    training and model metrics: ``eval/video_accuracy`` (each video voted by its items' averaged
    class scores, :mod:`edr.tasks.predictions`), ``eval/item_accuracy`` (over test items, each
    a 10-crop stack) and ``eval/accuracy``, the item accuracy under the name every earlier
    record and table reads."""
    tested = tested if tested is not None else evaluate(model, test_set, dev)
    scores, confusion = classification_metrics(tested.predicted, tested.true, classes)
    videos = video_predictions(test_set.videos, [i for i, _ in test_set.items], tested.scores)
    write_predictions(out_dir / PREDICTIONS, classes, videos)
    probe = torch.stack([train_set[i][0] for i in range(min(4, len(train_set)))]).to(dev)
    model.eval()
    sparsity = activation_sparsity(model, probe)
    model.cpu()
    save_atomic({"state_dict": model.state_dict(), **rebuild}, out_dir / MODEL)
    write_json_atomic(out_dir / HISTORY, history)
    write_json_atomic(out_dir / CONFUSION, confusion)
    save_learning_curve(history, out_dir / "learning_curve.png")
    save_confusion(np.array(confusion["matrix"]), classes, out_dir / "confusion.png")
    return {
        **scores,
        "eval/item_accuracy": scores["eval/accuracy"],
        "eval/video_accuracy": video_accuracy(videos),
        "train/epochs": len(history),
        "train/loss": history[-1]["train/loss"] if history else float("nan"),
        "model/parameters": sum(p.numel() for p in model.parameters()),
        **{f"sparsity/{name}": value for name, value in sparsity.items()},
        **_learned(model.representation),
    }


def _check_sizes(
    crop: int, resize: Sequence[int], frames: int, batch_size: int, channels: int,
    representation: Representation,
) -> None:  # fmt: skip
    """One line for a crop larger than the frames, clips too short for the representation, or
    sizes whose clips or batches cannot fit in memory."""
    if crop > min(resize):
        raise ConfigError(
            f"task.crop={crop}: expected at most the frames' short side, {min(resize)} "
            f"(task.resize={list(resize)}): a crop is cut from a frame, then resized"
        )
    check_enough_frames(frames, {"the representation": representation})
    check_decoded_memory(resize, frames, channels)
    in_frames = _backbone_frames(representation, frames)
    check_memory(
        f"task.batch_size={batch_size}, task.frames={frames}, task.crop={crop}",
        f"a batch of the backbone's input ({batch_size} clips of {in_frames} frames at "
        f"{crop}x{crop}, float32)",
        batch_size * in_frames * representation.out_channels(channels) * crop * crop * 4,
    )


def _check_backbone_takes(
    backbone: Callable[..., nn.Module], representation: Representation, channels: int,
    frames: int, crop: int,
) -> None:  # fmt: skip
    """One line, before any video is decoded, for clips the backbone cannot take (a crop
    smaller than its convolutions and pooling need): one clip of zeros through a fresh one."""
    in_frames = _backbone_frames(representation, frames)
    in_channels = representation.out_channels(channels)
    try:  # on a fork of torch's generator: the run's own weights and clips stay as they were
        with torch.random.fork_rng(), torch.no_grad():  # a backbone may probe its sizes as built
            network = backbone(in_channels=in_channels, num_classes=2, frames=in_frames,
                               height=crop, width=crop)  # fmt: skip
            network.eval()(torch.zeros(1, in_frames, in_channels, crop, crop))
    except RuntimeError as error:
        reason = " ".join(str(error).split())[:160]
        raise ConfigError(
            f"task.crop={crop}, task.frames={frames}: the backbone "
            f"cannot take clips of {in_frames} frames at {crop}x{crop} ({reason}): use a "
            "larger task.crop (or more task.frames)"
        ) from None


def _backbone_frames(representation: Representation, frames: int) -> int:
    """The frames of a clip the backbone sees, of ``frames`` decoded: a precomputed
    representation's clip has as many, one computed on the fly as many as it makes of them."""
    return frames if representation.precompute else representation.out_frames(frames)


def _check_every_class_trains(root: Path, train_videos: VideoSet) -> None:
    """One line for a class with no training video (it cannot be learned, nor is chance 1/K)."""
    classes = train_videos.classes
    untrained = sorted(set(classes) - {classes[v.label] for v in train_videos.videos})
    if untrained:
        raise ConfigError(
            f"{root}: the training split holds no video of {', '.join(untrained)}: a class "
            f"without training videos cannot be learned (nor is chance 1/{len(classes)}); "
            "give it videos, or remove it from the data set"
        )


def _clip_sets(
    representation: Representation, frame_source: VideoSource, cache_dir: str, data: _Data,
    frames: int, crop: int, scales: Sequence[float], control: FrameControl | None,
) -> tuple[Representation | None, ClipDataset, ClipDataset, int]:  # fmt: skip
    """Every video decoded (and, for a precomputed representation, computed once, like the
    paper's flows) into the caches; returns the representation the model computes on the fly
    (None when precomputed), the training and test clips, and the frames of a clip the
    backbone sees."""
    paths = [v.path for v in data.train.videos + data.test.videos]
    frame_source.cache.fill(paths, frame_source.decode, desc="decoding")
    if representation.precompute:
        source: Callable = PrecomputedSource(frame_source, representation, cache_dir)
        name = type(representation).__name__
        source.cache.fill(paths, source.compute, desc=f"precomputing {name}")
        online, negate = None, representation.hflip_negate
    else:
        source, online, negate = frame_source, representation, ()
    clips = {"frames": frames, "crop": crop, "negate": negate, "control": control}
    train_set = ClipDataset(data.train, source, train=True, scales=scales, **clips)
    test_set = ClipDataset(data.test, source, train=False, **clips)
    return online, train_set, test_set, _backbone_frames(representation, frames)


def _train_epoch(
    model: RecognitionModel, opt: torch.optim.Optimizer, loader: DataLoader, dev: torch.device,
    epoch: int, epochs: int,
) -> tuple[dict[str, float], dict[str, Any]]:  # fmt: skip
    """One epoch of ``loader``'s clips: the history row's training part (loss, accuracy, a
    learnable EDR's mean gradient norm), and where the training diverged if it did."""
    model.train()
    online = model.representation
    learnable = isinstance(online, EDR) and online.learnable
    loss_fn = nn.CrossEntropyLoss()
    total, correct, loss_sum, edr_grad_norms = 0, 0, 0.0, []
    bar = tqdm(loader, desc=f"epoch {epoch + 1}/{epochs}", unit="batch")
    for step, (clips, labels) in enumerate(bar, start=1):
        interrupts.raise_if_stopping()  # a Ctrl-C some callback dropped stops here
        clips, labels = clips.to(dev), labels.to(dev)
        logits = model(clips)
        loss = loss_fn(logits, labels)
        reason = divergence(model, loss)
        if reason is None:
            opt.zero_grad(set_to_none=True)
            loss.backward()
            if learnable:  # the EDR layer's gradient, before the step: its stability
                edr_grad_norms.append(_grad_norm(online))
            opt.step()
            # a step can leave NaN in a layer the loss skips, or a learned EDR value
            # outside its range (no events, ON and OFF swapped) while the loss is a number
            reason = divergence(model) or (online.out_of_range() if learnable else None)
        if reason is not None:  # diverged: a result to record, not a crash
            bar.close()
            return {}, {
                "train/diverged_epoch": epoch + 1,
                "train/diverged_step": epoch * len(loader) + step,
                "train/diverged_reason": reason,
            }
        total += len(labels)
        correct += int((logits.argmax(-1) == labels).sum())
        loss_sum += loss.item() * len(labels)
        bar.set_postfix(loss=f"{loss_sum / total:.3f}", acc=f"{correct / total:.2f}")
    row = {"epoch": epoch + 1, "train/loss": loss_sum / total, "train/accuracy": correct / total}
    if edr_grad_norms:
        row["edr/grad_norm"] = float(np.mean(edr_grad_norms))  # mean over the epoch's steps
    return row, {}


def check_decoded_memory(
    resize: Sequence[int], frames: int, channels: int, where: str = "task"
) -> None:
    """Refuse a frame size whose clip cannot fit in memory: a clip's ``frames`` decoded frames
    at ``resize``, held whole (or padded to ``frames`` from a shorter video); ``where``: the
    settings' section in the config."""
    width, height = resize
    check_memory(
        f"{where}.resize={list(resize)}, {where}.frames={frames}",
        f"a clip's {frames} decoded frames at {width}x{height}", frames * channels * width * height,
    )  # fmt: skip


def data_labels(
    data_root: str | None, synthetic: Callable[..., Path], videos: VideoSet, count: int
) -> dict[str, str]:
    """``data/source`` (what the tables group and describe by) and ``data/label`` (a row's
    words, with the ``count`` of videos); split in time or by person, both say so, and the
    record says how (``data/split``)."""
    # a writer built from real videos says so (edr.data.from_videos); the rest generate
    source = "real" if data_root else getattr(synthetic.func, "data_source", "generated")
    clips = "real clips" if source == "real" else source
    if videos.time_split is not None:
        fraction = videos.time_split.train_fraction
        return {
            "data/source": f"{clips}, split in time",
            "data/label": f"{clips} ({count} videos), split in time",
            "data/split": f"in time, not the paper's protocol: each video's first {fraction:g} of "
            "its frames (less a gap of one clip) trains, its last part tests",
        }
    if videos.person_fold is not None:
        folds = videos.person_fold[1]
        return {
            "data/source": f"{clips}, split by person",
            "data/label": f"{clips} ({count} videos, {len(videos.classes)} classes), split by person",
            "data/split": f"by person, cross-validated over {folds} folds: each fold's persons "
            "test, the others' train, every video tested once (not the paper's random 75/25)",
        }
    return {"data/source": source, "data/label": source}


def _grad_norm(module: nn.Module) -> float:
    """The L2 norm of the gradient of every parameter of ``module``, together."""
    grads = [p.grad.detach().flatten() for p in module.parameters() if p.grad is not None]
    return float(torch.linalg.vector_norm(torch.cat(grads))) if grads else 0.0


def _learned(representation: Representation | None) -> dict[str, float]:
    """A learnable EDR's current values (``edr/tau_0``, ...); nothing for any other layer."""
    if isinstance(representation, EDR) and representation.learnable:
        return representation.settings_now()
    return {}


@functools.wraps(fit_recognition)
def train_recognition(**settings: Any) -> dict[str, Any]:
    """``fit_recognition``'s metrics: the entry of the KTH and UCF-101 tasks. Videos split by
    person into folds (``task.videos.protocol=person_folds``) are cross-validated: a network
    trained per fold, each in ``fold<k>/``, and their test predictions pooled
    (``task.videos.folds=persons``: a fold per person, every person held out once)."""
    videos = settings["videos"]
    keywords = getattr(videos, "keywords", {})
    if keywords.get("protocol") != "person_folds":
        return fit_recognition(**settings).metrics
    return _cross_validated(_fold_count(settings), settings)


def fold_means(fitted: list[dict[str, Any]]) -> dict[str, Any]:
    """The folds' metrics as one run's: a number every fold holds averaged over the folds, any
    other value as the first fold holds it, and where a fold diverged, the first diverged fold's
    ``train/diverged_*`` (its step counted within that fold) with ``train/diverged_fold``."""

    def number(value: Any) -> bool:
        return isinstance(value, int | float) and not isinstance(value, bool)

    shared = {k for k in fitted[0] if all(number(f.get(k)) for f in fitted)}
    diverged = next((k for k, f in enumerate(fitted) if "train/diverged_step" in f), None)
    merged = {k: v for k, v in fitted[0].items() if not k.startswith("train/diverged")}
    merged |= {
        k: float(np.mean([f[k] for f in fitted]))
        for k in shared
        if not k.startswith("train/diverged")
    }
    if diverged is not None:
        merged |= {k: v for k, v in fitted[diverged].items() if k.startswith("train/diverged")}
        merged["train/diverged_fold"] = diverged
    return merged


def _fold_count(settings: dict[str, Any]) -> int:
    """How many folds a split by person has: ``task.videos.folds``, or with ``persons`` the
    number of persons in the videos (listed, not decoded)."""
    folds = settings["videos"].keywords.get("folds", 2)
    if folds != "persons":
        return folds
    root = resolve_root(settings.get("data_root"), settings["synthetic"], settings["cache_dir"])
    return settings["videos"](root, train=False, fold=0).person_fold[1]


def _person_folds_problem(values: Mapping[str, Any]) -> str | None:
    """A split by person into more folds than the videos have persons, said before the run's
    record is written (the data set says it only once the run builds its data): the persons
    under ``data_root`` as the data set counts them, from the file names it lists (nothing
    decoded; its own one line, naming the folder, passes through), or those a generated set
    would hold, its ``synthetic.persons`` (nothing generated)."""
    videos = values.get("videos")
    if not isinstance(videos, Mapping) or videos.get("protocol") != "person_folds":
        return None
    folds = videos.get("folds", 2)
    if folds == "persons":
        return None
    if values.get("data_root"):
        instantiate(videos)(Path(values["data_root"]), train=False, fold=0)
        return None
    persons = (values.get("synthetic") or {}).get("persons")
    whose = f"the persons task.synthetic.persons={persons} generates"
    return folds_problem(folds, persons, whose) if isinstance(persons, int) else None


# What edr-run checks before any work (edr.checks.config.check_together)
train_recognition.settings_problem = _person_folds_problem  # type: ignore[attr-defined]
train_recognition.check_resumable = check_resumable  # type: ignore[attr-defined]  # edr-run calls it


def _cross_validated(folds: int, settings: dict[str, Any]) -> dict[str, Any]:
    """Every fold of a split by person, trained and tested in ``<out_dir>/fold<k>/`` (a fold
    that finished keeps its ``fold.json`` and ``predictions.json`` and is not trained again when
    the run resumes); the metrics of their pooled test predictions (each video tested once:
    video accuracy over the pooled ``predictions.json``, item accuracy over every test item of
    every fold), each fold's item accuracy, and the other metrics averaged over folds."""
    out_dir, resume = Path(settings["out_dir"]), bool(settings.get("resume"))
    fitted, matrix, classes, videos = [], None, None, []
    for fold in range(folds):
        fold_dir = out_dir / f"fold{fold}"
        fold_dir.mkdir(parents=True, exist_ok=True)
        done = fold_dir / FOLD_METRICS
        if not _fold_done(fold_dir):
            log.info("fold %d of %d", fold + 1, folds)
            seed_everything(settings["seed"] + 1000 * fold)  # a fold trains alike, resumed or not
            metrics = fit_recognition(**{
                **settings, "out_dir": fold_dir, "videos": functools.partial(settings["videos"], fold=fold),
                "resume": resume and (fold_dir / CHECKPOINT).is_file(),
            }).metrics  # fmt: skip
            write_json_atomic(done, metrics)
        fitted.append(json.loads(done.read_text()))
        tested = json.loads((fold_dir / PREDICTIONS).read_text())["videos"]
        videos += [{**entry, "fold": fold} for entry in tested]
        confusion = json.loads((fold_dir / CONFUSION).read_text())
        classes = confusion["classes"]
        matrix = np.array(confusion["matrix"]) + (0 if matrix is None else matrix)
    per_class = matrix.diagonal() / np.maximum(matrix.sum(1), 1)
    write_json_atomic(out_dir / CONFUSION, {"classes": classes, "rows": "true class",
                                            "matrix": matrix.tolist()})  # fmt: skip
    save_confusion(matrix, classes, out_dir / "confusion.png")
    write_predictions(out_dir / PREDICTIONS, classes, videos)
    pooled = float(matrix.trace() / matrix.sum())
    if any(np.isnan(f["eval/accuracy"]) for f in fitted):  # a fold diverged: no pooled accuracy
        pooled = float("nan")
    return {
        **fold_means(fitted),
        "data/test_videos": sum(f["data/test_videos"] for f in fitted),
        "data/test_clips": sum(f["data/test_clips"] for f in fitted),
        "data/folds": folds,
        **{f"eval/fold{k}/accuracy": f["eval/accuracy"] for k, f in enumerate(fitted)},
        "eval/accuracy": pooled,
        "eval/item_accuracy": pooled,
        "eval/video_accuracy": float("nan") if np.isnan(pooled) else video_accuracy(videos),
        **{f"eval/per_class/{c}": float(a) for c, a in zip(classes, per_class, strict=True)},
    }
