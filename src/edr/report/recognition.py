"""Video recognition tables: Table 2 (UCF-101 with LTC, beside the speed column), Table 4 (KTH,
ConvNet+RCN backbones), Appendix A (DVS transfer) and the EDR ablations."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import pandas as pd

from edr.report.published import cite, lookup, paper_accuracy, paper_name
from edr.report.render import Table, mean_std, uncommitted
from edr.report.runs import cells, finished, placeable, unfinished
from edr.report.speed import BENCH_ROWS, bench_fps, ratio_lines
from edr.report.video_statistics import by_person_block

ACCURACY = "metrics.eval/accuracy"
ABLATION_KEYS = ("half_lives", "beta", "nu_on", "nu_off", "threshold", "return_form", "combine")
LEARNABLE = {  # the ablations the learnable-EDR block compares, with FDR, as its rows say them
    "paper": "EDR, fixed (the paper's values)",
    "learnable_log": "EDR, learnable (tau through its log)",
    "learnable_bounded": "EDR, learnable (bounded: sigmoids, exp)",
}
LEARNED = {"tau_0": "half_lives", "beta_0": "beta", "nu_on_0": "nu_on", "nu_off_0": "nu_off"}
LEARNED_COLUMNS = {"tau_0": "Half-life (frames)", "beta_0": "beta", "nu_on_0": "nu_on",
                   "nu_off_0": "nu_off"}  # fmt: skip
DIVERGED = "metrics.train/diverged_step"
# A record's ``data/frame_order`` under a control -> the words a row's representation gets
# ("shuffled": the within-clip control's word in records before 2026-12-07).
FRAME_QUALIFIERS = {
    "shuffled": "frames shuffled within each clip, motion statistics survive",
    "shuffled within each clip": "frames shuffled within each clip, motion statistics survive",
    "shuffled within the video": "frames shuffled within the video",
    "one frame repeated": "one frame repeated, no motion",
}


def without_ablations(runs: pd.DataFrame) -> pd.DataFrame:
    """Runs of the named representations as they are (no ``ablation=`` change, or ``paper``)."""
    if "choices.ablation" not in runs:
        return runs
    return runs[runs["choices.ablation"].isin(["None", "paper"]) | runs["choices.ablation"].isna()]


def only_ablations(runs: pd.DataFrame) -> pd.DataFrame:
    """Runs of the ablation sweep: an ``ablation=`` choice made (``paper`` included)."""
    if "choices.ablation" not in runs:
        return runs.iloc[0:0]
    return runs[runs["choices.ablation"].notna() & (runs["choices.ablation"] != "None")]


def standardised(done: pd.DataFrame) -> pd.Series:
    """Whether each run's input was standardised before the backbone; raw where the record
    predates ``task.normalize_input`` (every record before 2026-12-03)."""
    missing = pd.Series(None, index=done.index, dtype=object)
    return done.get("config.task.normalize_input", missing).eq(True)


def labelled(done: pd.DataFrame) -> pd.DataFrame:
    """``done`` with what a row of Table 2 or 4 is labelled by: ``data.label`` (the data's words,
    "real clips (8 videos), split in time"; older records: their source) and ``input`` (the
    representation, qualified "raw input" where it reached the backbone unstandardised, as in
    every record before ``task.normalize_input`` became the default, and by the control its
    frames had, :data:`FRAME_QUALIFIERS`)."""
    if done.empty:
        return done.assign(**{"data.label": None, "input": None})
    missing = pd.Series(None, index=done.index, dtype=object)
    raw = ~standardised(done)
    control = done.get("data.frame_order", missing).map(FRAME_QUALIFIERS)
    qualifiers = pd.Series(
        [", ".join(q for q, on in (("raw input", r), (c, isinstance(c, str))) if on)
         for r, c in zip(raw, control, strict=True)],
        index=done.index,
    )  # fmt: skip
    representation = done.get("choices.representation", missing).astype(str)
    return done.assign(
        **{
            "data.label": done.get("data.label", missing).fillna(done["data.source"]),
            "input": representation.where(
                qualifiers == "", representation + " (" + qualifiers + ")"
            ),
        }
    )


SPLIT_IN_TIME_NOTE = (
    "Data 'real clips (N videos), split in time': the few real clips of ../shared/real-video "
    "(experiment=kth_real, ucf101_real), each video's first part for training and its last part "
    "for testing, a clip's length apart: not the paper's protocol (the published number beside "
    "them is the paper's on its own split); their accuracy is over test clips (several per video). "
    "'frames shuffled within each clip, motion statistics survive' (task.shuffle_frames): each "
    "clip's frames in a random order once it is cut, so neighbouring frames stay close in time "
    "and a representation of them still sees motion: not appearance alone. 'one frame "
    "repeated, no motion' (task.frame_control=one_frame): one frame of each clip over all its "
    "frames, appearance alone; 'frames shuffled within the video' "
    "(task.frame_control=shuffled_in_video): each video's frames in one random order before "
    "clips are cut. "
    "'raw input': the representation reached the backbone as computed "
    "(task.normalize_input=false, as every record before 2026-12-03 ran); without it, each input "
    "channel was standardised first (the default since)."
)


PUBLISHED_NOTE = (
    "Published: the paper's accuracy for the row's backbone and representation (Table 4: KTH; "
    "Table 2: UCF-101 split 1 with LTC), on its data set under its protocol, beside every row of "
    "that setting whatever data the row ran on: a reference, not the same measurement where the "
    "Data column names other data. '—' where the paper reports none (another backbone or "
    "representation, EDR with other settings, a control of the frames); see paper/published.yaml."
)


UCF101_SPLITS_NOTE = (
    "No row runs UCF-101's official split lists, because the real clips allow no experiment on "
    "them: of the 24 real UCF-101 clips of 13 classes in ../shared/real-video/ucf101, the lists "
    "put clips of a class on both sides for 2 classes in split 1 (Biking, Rowing: 3 test clips, "
    "trained on 7), 2 in split 2 (PlayingViolin, Rowing: 4 test clips, trained on 6) and 3 in "
    "split 3 (Biking, PlayingViolin, Rowing: 5 test clips, trained on 8); one test clip would "
    "move accuracy by 20 to 33 points (tests/test_ucf101_lists.py counts them)."
)


def _first_runs(grouped: pd.DataFrame, done: pd.DataFrame) -> list[pd.Series]:
    """Per row of ``grouped`` (cells of ``done``), its first run: the settings its runs share."""
    by_record = done.set_index("record")
    by_record = by_record[~by_record.index.duplicated()]
    return [by_record.loc[records[0]] for records in grouped["records"]]


def _paper_name(run: pd.Series, published: dict[str, Any]) -> str | None:
    """The name published.yaml gives a run's representation (None: an EDR of settings the paper
    did not run), from its ``config.representation`` settings."""
    prefix = "config.representation."
    settings = {k.removeprefix(prefix): v for k, v in run.items() if k.startswith(prefix)}
    return paper_name(published, str(run.get("choices.representation")), settings)


def paper_names(
    grouped: pd.DataFrame, done: pd.DataFrame, published: dict[str, Any]
) -> list[str | None]:
    """Per row of ``grouped`` (cells of ``done``), :func:`_paper_name` of its runs."""
    return [_paper_name(run, published) for run in _first_runs(grouped, done)]


def published_accuracy(
    grouped: pd.DataFrame, done: pd.DataFrame, published: dict[str, Any]
) -> list[str]:
    """Per row of ``grouped`` (cells of ``done``), the paper's accuracy for its task, backbone
    and representation as a table cell, whatever data the row ran on (:data:`PUBLISHED_NOTE`);
    '—' where the paper has none, and beside a control of the frames (no setting of the
    paper's)."""
    return [
        cite(
            None
            if run.get("data.frame_order") in FRAME_QUALIFIERS
            else paper_accuracy(
                published, run.get("task"), run.get("choices.backbone"), _paper_name(run, published)
            )
        )
        for run in _first_runs(grouped, done)
    ]


def _accuracy_rows(
    grouped: pd.DataFrame, columns: dict[str, str], published: list[str]
) -> pd.DataFrame:
    """Display rows: the label ``columns`` (column -> heading), accuracy, runs, chance, and the
    ``published`` cells (:func:`published_accuracy`)."""
    return pd.DataFrame(
        {
            **{heading: grouped[column] for column, heading in columns.items()},
            "Accuracy (%)": [
                mean_std(m, s, 100)
                for m, s in zip(
                    grouped[f"{ACCURACY}:mean"], grouped[f"{ACCURACY}:std"], strict=True
                )
            ],
            "Runs (seeds)": [
                f"{n} ({', '.join(map(str, s))})"
                for n, s in zip(grouped["runs"], grouped["seeds"], strict=True)
            ],
            "Chance (%)": [f"{100 * c:.1f}" for c in grouped["metrics.eval/chance:mean"]],
            "Published (%)": published,
            "Cell": grouped["cell"].str[:8],
        }
    )


def table4_kth(runs: pd.DataFrame, published: dict[str, Any]) -> Table:
    done = labelled(finished(runs, "kth", without_ablations))
    done, unplaced = placeable(done, ["choices.backbone", "choices.representation"], ACCURACY)
    labels = ["data.label", "choices.backbone", "choices.representation", "input"]
    grouped = cells(done, [ACCURACY, "metrics.eval/chance"], labels)
    frame = (
        pd.DataFrame()
        if grouped.empty
        else _accuracy_rows(
            grouped,
            {
                "choices.backbone": "Backbone",
                "input": "Representation",
                "data.label": "Data",
                "scale": "Scale",
            },
            published_accuracy(grouped, done, published),
        )
    )
    return Table(
        "table4_kth",
        "Table 4: KTH, ConvNet + recurrent head x representation, ours beside the paper's",
        frame,
        done,
        notes=[
            "Accuracy: over test items (`eval/accuracy`), each a 10-crop stack with its softmax "
            "averaged: one item per video on generated data, one per KTH sub-sequence split by "
            "person (4 a video), several stretches a video split in time; ± is the spread over "
            "seeds on the same items, not an interval. Rows split by person are counted in "
            "videos, with intervals and paired tests, below the table. Cell: the config "
            "fingerprint without the seed; rows with the same labels and another cell differ in "
            "some other setting.",
            PUBLISHED_NOTE,
            SPLIT_IN_TIME_NOTE,
        ],
        extra=by_person_block(done),
        unfinished=unfinished(runs, "kth", unplaced),
        paper=pd.DataFrame(
            [
                {"Backbone": backbone, "Representation": rep, "Accuracy (%)": cite(acc)}
                for backbone, by_rep in (lookup(published, "table4_kth", "accuracy") or {}).items()
                for rep, acc in by_rep.items()
            ]
        ),
        paper_notes=_paper_notes(published, "table4_kth"),
    )


def _paper_notes(published: dict[str, Any], key: str) -> list[str]:
    """The source line and the inconsistency notes of one table of the published numbers."""
    source = lookup(published, key, "source")
    return [*([f"Source: {source}."] if source else []), *(lookup(published, key, "notes") or [])]


def table2_ucf101(
    runs: pd.DataFrame, published: dict[str, Any], speed: dict[str, Any] | None
) -> Table:
    done = labelled(finished(runs, "ucf101", without_ablations))
    done, unplaced = placeable(done, ["choices.representation", "choices.backbone"], ACCURACY)
    labels = ["data.label", "choices.representation", "input", "choices.backbone"]
    grouped = cells(done, [ACCURACY, "metrics.eval/chance"], labels)
    frame = pd.DataFrame()
    if not grouped.empty:
        frame = _accuracy_rows(
            grouped,
            {
                "input": "Representation",
                "choices.backbone": "Backbone",
                "data.label": "Data",
                "scale": "Scale",
            },
            published_accuracy(grouped, done, published),
        )
        bench_rows = speed["rows"] if speed else []
        ours = [
            bench_fps(bench_rows, *BENCH_ROWS[r]) if r in BENCH_ROWS else None
            for r in grouped["choices.representation"]
        ]
        frame.insert(5, "Speed (fps)", [f"{fps:,.0f}" if fps else "—" for fps in ours])
        frame.insert(
            6,
            "Published (fps)",
            [
                cite(lookup(published, "speed", "fps", name) if name else None, ",.1f")
                for name in paper_names(grouped, done, published)
            ],
        )
    machine = speed["machine"] if speed else {}
    extra = ""
    if speed:
        extra = "\n".join(
            [
                f"Speed: `edr-bench` on {machine.get('cpu')} ({machine.get('cpu_count')} cores), "
                f"{speed['clip']}, {speed['measured_at']}, git `{speed['git']}`. "
                + (f"Uncommitted code: {dirty}. " if (dirty := uncommitted([speed["git"]])) else "")
                + "Ratios from that one run:",
                "",
                *ratio_lines([speed["rows"]], published.get("speed", {})),
            ]
        )
    return Table(
        "table2_ucf101",
        "Table 2: LTC, accuracy and speed per representation (the paper's on UCF-101 split 1; "
        "ours on the data each row names)",
        frame,
        done,
        notes=[
            "Accuracy as in Table 4; speed from the newest `edr-bench` record (see "
            "table2_speed.md for every timed row), beside the paper's for the representation.",
            PUBLISHED_NOTE,
            SPLIT_IN_TIME_NOTE,
            UCF101_SPLITS_NOTE,
        ],
        unfinished=unfinished(runs, "ucf101", unplaced),
        extra=extra,
        paper=pd.DataFrame(
            [
                {
                    "Representation": rep,
                    "Accuracy (%)": cite(acc),
                    "Speed (fps)": cite(lookup(published, "speed", "fps", rep), ",.1f"),
                }
                for rep, acc in (
                    lookup(published, "table2_ucf101", "accuracy", "ltc") or {}
                ).items()
            ]
        ),
        paper_notes=_paper_notes(published, "table2_ucf101") + _paper_notes(published, "speed"),
    )


def appendix_a_dvs(runs: pd.DataFrame, published: dict[str, Any]) -> Table:
    done = finished(runs, "dvs_transfer")
    metrics = [
        ACCURACY,
        "metrics.eval/zero_shot_accuracy",
        "metrics.pretrain/eval/accuracy",
        "metrics.eval/chance",
    ]
    done, unplaced = placeable(done, ["choices.backbone", "data.events"], ACCURACY)
    grouped = cells(done, metrics, ["choices.backbone", "data.events"])
    frame = pd.DataFrame()
    if not grouped.empty:
        frame = pd.DataFrame(
            {
                "Backbone": grouped["choices.backbone"],
                "Events": grouped["data.events"],
                "Data": grouped["data.source"],
                "Scale": grouped["scale"],
                "Pre-trained (%)": [
                    mean_std(grouped[f"{metrics[2]}:mean"][i], grouped[f"{metrics[2]}:std"][i], 100)
                    for i in grouped.index
                ],
                "Zero-shot (%)": [
                    mean_std(grouped[f"{metrics[1]}:mean"][i], grouped[f"{metrics[1]}:std"][i], 100)
                    for i in grouped.index
                ],
                "Fine-tuned (%)": [
                    mean_std(grouped[f"{ACCURACY}:mean"][i], grouped[f"{ACCURACY}:std"][i], 100)
                    for i in grouped.index
                ],
                "Published fine-tuned (%)": cite(
                    lookup(published, "appendix_a_dvs", "finetuned_accuracy")
                ),
                "Runs": grouped["runs"],
                "Chance (%)": [f"{100 * c:.1f}" for c in grouped["metrics.eval/chance:mean"]],
            }
        )
    return Table(
        "appendix_a_dvs",
        "Appendix A: a ConvNet+RCN pre-trained on EDR (the paper: on KTH; ours: on the data the "
        "Data column names), on event-camera frames, zero-shot and fine-tuned",
        frame,
        done,
        notes=[
            "Pre-trained: the network's accuracy on its pre-training data (the Data column: "
            "generated data is not KTH). Fine-tuned on 70 % of the recordings per class, tested "
            "on the other 30 %. Events: simulated by our DVS simulator unless recordings are named.",
            "Published fine-tuned: the paper's, beside every row: its ConvNet+RCN pre-trained on "
            "KTH, fine-tuned and tested on its DVS128 recordings of KTH clips shown on a screen "
            "(a reference, not the same measurement where the Data and Events columns name "
            "others).",
        ],
        unfinished=unfinished(runs, "dvs_transfer", unplaced),
        paper=pd.DataFrame(
            [
                {
                    "Events": "DVS128 recordings of KTH clips on a screen (10 per class)",
                    "Zero-shot (%)": cite(
                        lookup(published, "appendix_a_dvs", "zero_shot_accuracy")
                    ),
                    "Fine-tuned (%)": cite(
                        lookup(published, "appendix_a_dvs", "finetuned_accuracy")
                    ),
                }
            ]
        ),
        paper_notes=_paper_notes(published, "appendix_a_dvs"),
    )


def _setting(values: Sequence[Any]) -> str:
    return ", ".join(map(str, values)) if isinstance(values, list | tuple) else str(values)


def ablation_edr(runs: pd.DataFrame, published: dict[str, Any]) -> Table:
    done = finished(runs, "kth", only_ablations)
    if not done.empty:  # learnable EDR has its own block, beside FDR
        done = done[~done["choices.ablation"].str.startswith("learnable")]
    keys = [f"config.representation.{k}" for k in ABLATION_KEYS]
    grouped = cells(done, [ACCURACY, "metrics.eval/chance"], ["choices.ablation", *keys])
    frame = pd.DataFrame()
    if not grouped.empty:
        frame = pd.DataFrame(
            {
                "Ablation": grouped["choices.ablation"],
                **{
                    k: [_setting(v) for v in grouped[f"config.representation.{k}"]]
                    for k in ABLATION_KEYS
                },
                "Data": grouped["data.source"],
                "Scale": grouped["scale"],
                "Accuracy (%)": [
                    mean_std(m, s, 100)
                    for m, s in zip(
                        grouped[f"{ACCURACY}:mean"], grouped[f"{ACCURACY}:std"], strict=True
                    )
                ],
                "Runs": grouped["runs"],
                "Published (%)": published_accuracy(grouped, done, published),
            }
        )
    learnable = learnable_runs(runs)
    return Table(
        "ablation_edr",
        "Ablations of EDR (LeNet + FT-RCN; the paper's on KTH, ours on the data each row names): "
        "one change each from the paper's EDR",
        frame,
        pd.concat([done, learnable]).drop_duplicates("record"),
        notes=[
            "`paper`: the paper's EDR (half-life 3.8 frames, ratio, soft, nu 0.05, beta 1); "
            "each other row changes what conf/ablation/<name>.yaml says.",
            PUBLISHED_NOTE,
        ],
        extra=_learnable_block(learnable, published),
    )


def learnable_runs(runs: pd.DataFrame) -> pd.DataFrame:
    """The runs of the learnable-EDR comparison, on KTH and on UCF-101's layout (the speed
    classes built from real videos): fixed and learnable EDR (``ablation=paper``,
    ``learnable_*``), and FDR with the same backbone on the same data at the same scale, as
    its control."""
    parts = []
    for task in ("kth", "ucf101"):
        done = finished(runs, task, only_ablations)
        edr = done[done["choices.ablation"].isin(list(LEARNABLE))] if not done.empty else done
        if edr.empty or not edr["choices.ablation"].str.startswith("learnable").any():
            continue

        def control(plain: pd.DataFrame, edr: pd.DataFrame = edr) -> pd.DataFrame:
            """FDR on the very data EDR had, its input standardised or raw as EDR's was
            (selected before the newest of one fingerprint is kept: a later run of the same
            config on other data is another table's)."""
            plain = without_ablations(plain)
            return plain[
                (plain["choices.representation"] == "fdr")
                & plain["data.fingerprint"].isin(set(edr["data.fingerprint"]))
                & plain["scale"].isin(set(edr["scale"]))
                & plain["choices.backbone"].isin(set(edr["choices.backbone"]))
                & standardised(plain).isin(set(standardised(edr)))
            ]

        fdr = finished(runs, task, control)
        parts += [fdr.assign(**{"choices.ablation": "fdr"}), edr]
    return pd.concat(parts) if parts else runs.iloc[:0]


def _learned_value(grouped: pd.Series, key: str, configured: Any) -> str:
    """A learned value as mean +- std over seeds, or the configured one when it is fixed."""
    mean = grouped.get(f"metrics.edr/{key}:mean", float("nan"))
    if pd.notna(mean):
        return mean_std(mean, grouped[f"metrics.edr/{key}:std"], fmt=".3g")
    return f"{_setting(configured)} (fixed)" if configured is not None else "—"


def _learnable_block(runs: pd.DataFrame, published: dict[str, Any]) -> str:
    """Markdown: accuracy, divergences and final values of fixed vs learnable EDR vs FDR."""
    if runs.empty:
        return ""
    runs = runs.assign(diverged=runs[DIVERGED].notna() if DIVERGED in runs else False)
    metrics = [ACCURACY, "diverged", *(f"metrics.edr/{k}" for k in LEARNED)]
    keys = [f"config.representation.{k}" for k in LEARNED.values()]
    for key in [*metrics, *keys]:
        if key not in runs:
            runs[key] = float("nan") if key.startswith("metrics") else None
    grouped = cells(runs, metrics, ["choices.ablation", *keys])
    order = ["fdr", *LEARNABLE]
    grouped = grouped.assign(order=grouped["choices.ablation"].map(order.index))
    grouped = grouped.sort_values(["data.source", "order"], kind="stable")  # one block per data
    rows = []
    paper = published_accuracy(grouped, runs, published)
    for (_, g), paper_cell in zip(grouped.iterrows(), paper, strict=True):
        ablation = g["choices.ablation"]
        learned = {
            name: "—" if ablation == "fdr" else _learned_value(
                g, key, g[f"config.representation.{LEARNED[key]}"] if ablation == "paper" else None
            )
            for key, name in LEARNED_COLUMNS.items()
        }  # fmt: skip
        rows.append(
            {
                "Input": LEARNABLE.get(ablation, "FDR (frames, no EDR)"),
                "Data": g["data.source"],
                "Scale": g["scale"],
                "Accuracy (%)": mean_std(g[f"{ACCURACY}:mean"], g[f"{ACCURACY}:std"], 100),
                "Runs": g["runs"],
                "Diverged": round(g["diverged:mean"] * g["runs"]),
                **learned,
                "Published (%)": paper_cell,
            }
        )
    return "\n".join(
        [
            "## Learnable EDR, trained end to end with the network",
            "",
            "Half-life, beta and nu of a learnable EDR start at the paper's values (half-life 3.8 "
            "frames, beta 1, nu 0.05) and train with the backbone; their final values are the "
            "mean +- std over seeds. Diverged: runs whose training loss stopped being a number "
            "(recorded with the step, `train/diverged_step`; their accuracy is not averaged). "
            "FDR: the same backbone and budget on the frames. Per-epoch values and the EDR "
            "layer's gradient norm: `figures/learnable_edr.png`. Published: as in the table "
            "above (the paper ran no learnable EDR).",
            "",
            pd.DataFrame(rows).to_markdown(index=False),
            "",
        ]
    )
