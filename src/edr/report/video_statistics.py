"""Table 4's rows split by person, counted in videos: each row's video accuracy with a 95 %
interval (percentile bootstrap over videos), paired comparisons between rows on the same videos
(an exact sign-flip test), each video's scenario, and the class-scenario confounds of the set.

A run votes each test video by the mean of its items' class scores (``predictions.json``,
:mod:`edr.tasks.predictions`); a row's runs (seeds) are averaged per video first, so a video is
one unit of evidence however many seeds ran it.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from edr.report.runs import PREDICTIONS, run_json

BOOTSTRAP_RESAMPLES = 10_000
BOOTSTRAP_SEED = 0
EXACT_UP_TO = 20  # videos that differ: beyond, random sign patterns (seeded)
RANDOM_PATTERNS = 100_000
ALPHA = 0.05


def bootstrap_interval(
    correct: np.ndarray, resamples: int = BOOTSTRAP_RESAMPLES, seed: int = BOOTSTRAP_SEED
) -> tuple[float, float]:
    """The 95 % percentile bootstrap interval of ``correct.mean()``, ``correct`` (videos,) each
    video's share of runs right, resampling videos with replacement (a fixed ``seed``)."""
    picks = np.random.default_rng(seed).integers(0, len(correct), (resamples, len(correct)))
    low, high = np.percentile(correct[picks].mean(1), [2.5, 97.5])
    return float(low), float(high)


def sign_flip_p(differences: np.ndarray, seed: int = BOOTSTRAP_SEED) -> float:
    """Two-sided p of the paired sign-flip (permutation) test that ``differences`` (videos,)
    centre on zero: the share of sign patterns whose sum is at least as far from zero as the
    observed one; exact (every pattern of the videos that differ) up to :data:`EXACT_UP_TO`
    of them, else :data:`RANDOM_PATTERNS` random patterns drawn with ``seed``."""
    d = differences[differences != 0]
    if not len(d):
        return 1.0
    observed = abs(d.sum()) - 1e-9  # a pattern as extreme as the data counts (float sums)
    if len(d) > EXACT_UP_TO:
        signs = np.random.default_rng(seed).choice([-1.0, 1.0], (RANDOM_PATTERNS, len(d)))
        return float(np.mean(np.abs(signs @ d) >= observed))
    extreme, low = 0, min(len(d), 16)  # patterns of the first ``low`` videos, per high pattern
    bits = (np.arange(2**low)[:, None] >> np.arange(low)) & 1  # (2**low, low)
    partial = (bits * 2 - 1) @ d[:low]  # (2**low,)
    for high in range(2 ** (len(d) - low)):
        rest = sum(v if high >> k & 1 else -v for k, v in enumerate(d[low:]))
        extreme += int(np.sum(np.abs(partial + rest) >= observed))
    return extreme / 2 ** len(d)


def confounds(videos: pd.DataFrame) -> tuple[str, list[str]]:
    """(each class's scenarios with their counts, the scenarios found in one class only) of
    ``videos`` (columns ``true`` and ``scenario``, a row per video)."""
    by_class = [
        f"{cls} " + ", ".join(f"{s} ({n})" for s, n in sorted(g["scenario"].value_counts().items()))
        for cls, g in videos.groupby("true", sort=True)
    ]
    classes = videos.groupby("scenario")["true"].unique()
    only = [f"{s} only in {c[0]}" for s, c in sorted(classes.items()) if len(c) == 1]
    return "; ".join(by_class), only


def _predictions(run_dir: str) -> list[dict[str, Any]] | None:
    """A run's per-video entries (checked as its record was read, :mod:`edr.report.runs`),
    None where it kept none (records before predictions.json)."""
    kept = run_json(Path(run_dir), PREDICTIONS)
    return None if kept is None else kept["videos"]


def _row(label: str, runs: pd.DataFrame) -> tuple[dict[str, Any], pd.DataFrame] | None:
    """One display row of a representation's runs and its videos (index: video; ``correct``:
    the share of its runs right; ``true``, ``person``, ``scenario``); None without
    predictions."""
    entries = [(seed, e) for seed, d in zip(runs["seed"], runs["run_dir"], strict=True)
               for e in (_predictions(d) or [])]  # fmt: skip
    if not entries:
        return None
    frame = pd.DataFrame(
        [
            {
                "seed": s,
                "video": e["video"],
                "true": e["true"],
                "person": e["person"],
                "scenario": e["scenario"],
                "right": e["predicted"] == e["true"],
                "items": len(e["items"]),
                "items_right": sum(i == e["true"] for i in e["items"]),
            }
            for s, e in entries
        ]
    )
    videos = frame.groupby("video").agg(
        correct=("right", "mean"), true=("true", "first"), person=("person", "first"),
        scenario=("scenario", "first"),
    )  # fmt: skip
    low, high = bootstrap_interval(videos["correct"].to_numpy())
    seeds = sorted(frame["seed"].unique().tolist())
    row = {
        "Representation": label,
        "Videos": len(videos),
        "Runs (seeds)": f"{len(seeds)} ({', '.join(map(str, seeds))})",
        "Video accuracy (%)": f"{100 * videos['correct'].mean():.1f}",
        "95 % interval (%)": f"{100 * low:.1f}–{100 * high:.1f}",
        "Item accuracy (%)": f"{100 * frame['items_right'].sum() / frame['items'].sum():.1f}",
        "Items per run": int(frame["items"].sum() / len(seeds)),
    }
    return row, videos


def _comparisons(rows: Sequence[tuple[str, pd.DataFrame]]) -> pd.DataFrame:
    """Every pair of rows on the videos both hold: the seed-averaged difference summed over
    videos, the sign-flip p, and what it allows a reader to say."""
    out = []
    for (a, va), (b, vb) in itertools.combinations(rows, 2):
        shared = va.index.intersection(vb.index)
        d = (va.loc[shared, "correct"] - vb.loc[shared, "correct"]).to_numpy()
        p = sign_flip_p(d)
        reading = "no difference shown"
        if p < ALPHA:
            reading = f"{a} above {b}" if d.sum() > 0 else f"{b} above {a}"
        out.append({"A": a, "B": b, "Videos": len(shared), "A − B (videos)": f"{d.sum():+.2f}",
                    "p (sign-flip)": f"{p:.3f}", "Reading": reading})  # fmt: skip
    return pd.DataFrame(out)


def by_person_block(done: pd.DataFrame) -> str:
    """Markdown: for each set of videos split by person in ``done`` (finished Table 4 runs,
    labelled: ``input``, ``data.label``), its rows counted in videos, each video's scenario and
    result per row, the paired comparisons, and the class-scenario confounds."""
    if done.empty or "data.split" not in done:
        return ""
    person = done[done["data.split"].astype(str).str.startswith("by person")]
    person = person.assign(folds=person.get("data.folds", pd.Series(2, index=person.index)))
    blocks = []
    sets = person.groupby(["data.label", "data.fingerprint", "folds"], sort=True, dropna=False)
    for (label, _, folds), runs in sets:
        rows, missing = [], 0
        for (name, _), cell in runs.groupby(["input", "cell"], sort=True):
            made = _row(str(name), cell)
            missing += made is None
            if made is not None:
                rows.append(made)
        persons = len({r["person"] for _, v in rows for r in v.to_dict("records")})
        every = " (every person held out once)" if persons and persons == folds else ""
        blocks.append(_block(f"{label}, {folds:g} person folds{every}", rows, missing))
    if not blocks:
        return ""
    return "\n".join(["## Split by person, counted in videos", "", _METHOD, "", *blocks])


_METHOD = (
    "Each video is tested once per run, by a network that never saw its person; the run votes "
    "it by the mean of its items' class scores (`predictions.json`; an item: a 10-crop stack "
    "per KTH sub-sequence). Video accuracy: the mean over videos of the share of the row's runs "
    "(seeds) that name the video's class, so a video counts once however many seeds ran it. "
    f"95 % interval: percentile bootstrap over videos ({BOOTSTRAP_RESAMPLES:,} resamples, seed "
    f"{BOOTSTRAP_SEED}). Paired comparisons on the same videos: an exact sign-flip "
    "(permutation) test of the per-video differences of those shares, two-sided, uncorrected "
    f"for the number of pairs; a row reads 'above' another only where p < {ALPHA}, else 'no "
    "difference shown'. Item accuracy: over every test item of every run, as `eval/accuracy`."
)


def _block(label: str, rows: list[tuple[dict[str, Any], pd.DataFrame]], missing: int) -> str:
    """Markdown for one set of videos: its rows, per-video results, pairs and confounds."""
    lines = [f"### {label}", ""]
    if missing:
        lines += [
            f"{missing} row(s) of these videos keep no per-video predictions (their records "
            "predate `predictions.json`): counted in items only, in the table above.",
            "",
        ]
    if not rows:
        return "\n".join(lines)
    lines += [
        pd.DataFrame([r for r, _ in rows]).to_markdown(index=False, disable_numparse=True),
        "",
    ]
    videos = pd.concat([v[["true", "person", "scenario"]] for _, v in rows])
    videos = videos[~videos.index.duplicated()].sort_values(["true", "person"])
    table = videos.rename(columns={"true": "Class", "person": "Person", "scenario": "Scenario"})
    for row, per_video in rows:  # the share of the row's runs right, per video
        table[row["Representation"]] = (
            per_video["correct"]
            .reindex(table.index)
            .map(lambda c: "—" if pd.isna(c) else f"{c:.2f}")
        )
    by_class, only = confounds(videos)
    lines += [
        "Per video: the share of each row's runs that name its class.",
        "",
        table.reset_index()
        .rename(columns={"video": "Video"})
        .to_markdown(index=False, disable_numparse=True),
        "",
        f"Scenarios by class: {by_class}. "
        + (
            f"Confounds: {', '.join(only)}: there the scene alone can name the class."
            if only
            else "No scenario belongs to one class only."
        ),
        "",
    ]
    pairs = _comparisons([(r["Representation"], v) for r, v in rows])
    if not pairs.empty:
        lines += [pairs.to_markdown(index=False, disable_numparse=True), ""]
    return "\n".join(lines)
