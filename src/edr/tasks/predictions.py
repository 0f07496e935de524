"""Per-video test predictions, kept beside a recognition run's record as ``predictions.json``:
each test video's name, person and scenario (KTH's, from its file name), true class, the
prediction of each of its test items, and its soft vote, the mean of its items' class scores,
whose argmax is the video's prediction (``eval/video_accuracy``)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from edr.data.datasets import VideoSet, kth_person_scenario, video_name
from edr.store.atomic import write_json_atomic

PREDICTIONS = "predictions.json"
VOTE = (
    "soft vote: a video's prediction is the argmax of the mean, over its test items (a test "
    "stack each: one per sub-sequence or per stretch of a split in time), of the items' class "
    "scores (each item's softmax averaged over its 10 crops)"
)


def video_predictions(
    videos: VideoSet, items: Sequence[int], scores: np.ndarray
) -> list[dict[str, Any]]:
    """One entry per video of ``videos`` that has test items: ``items`` names each item's video
    (an index into ``videos``), ``scores`` (items, classes) its class scores."""
    classes, items = videos.classes, np.asarray(items)
    entries = []
    for i, video in enumerate(videos.videos):
        mine = scores[items == i]  # (its items, classes)
        if not len(mine):
            continue
        vote = mine.mean(0)  # (classes,)
        person, scenario = kth_person_scenario(video.path)
        entries.append(
            {
                "video": video_name(video.path),
                "person": person,
                "scenario": scenario,
                "true": classes[video.label],
                "predicted": classes[int(vote.argmax())],
                "items": [classes[k] for k in mine.argmax(1)],
                "soft_vote": [round(float(p), 6) for p in vote],
            }
        )
    return entries


def video_accuracy(entries: Sequence[dict[str, Any]]) -> float:
    """The share of videos whose soft vote names their class."""
    return float(np.mean([e["predicted"] == e["true"] for e in entries]))


def write_predictions(path: Path, classes: Sequence[str], entries: list[dict[str, Any]]) -> None:
    """``predictions.json``: the classes (the order of every ``soft_vote``), how a video is
    voted, and the entries."""
    write_json_atomic(path, {"classes": list(classes), "vote": VOTE, "videos": entries})
