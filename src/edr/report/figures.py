"""The paper's figures from run records: each a PNG and a caption file (``<name>.md``) that says
which data, which scale, which machine and which records it shows. A figure whose runs do not
exist yet is not drawn."""

from __future__ import annotations

import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import pandas as pd

from edr.report.atari import atari_runs, normalised_scores, seeded_bootstrap
from edr.report.published import cite, lookup
from edr.report.recognition import labelled, learnable_runs, without_ablations
from edr.report.render import paper_heading, provenance
from edr.report.runs import (
    CELL_KEYS,
    CONFUSION,
    PIXEL_RESPONSE,
    finished,
    run_file,
    run_history,
    run_json,
)
from edr.store.atomic import atomic_path, save_figure, write_text_atomic

Draw = Callable[[], "plt.Figure | None"]


def _cells(runs: pd.DataFrame, labels: list[str]) -> list[tuple[str, pd.DataFrame]]:
    """(label, runs) per cell: the runs a line or bar may average. Cells whose ``labels`` agree
    (they differ in another setting) are told apart by their cell, as the tables' Cell column;
    a label no record has (a record without choices) is shown as '?'."""
    found = [
        (
            " / ".join(str(group[label].iloc[0]) if label in group else "?" for label in labels),
            group,
        )
        for _, group in runs.groupby(CELL_KEYS, dropna=False, sort=True)
    ]
    names = [name for name, _ in found]
    return [
        (
            f"{name} [cell {str(group['cell'].iloc[0])[:8]}]" if names.count(name) > 1 else name,
            group,
        )
        for name, group in found
    ]


def label_styles(panels: list[pd.DataFrame], labels: list[str]) -> dict[str, int]:
    """A style number per label of the cells of each panel's runs, in order: one look per
    label in a figure (whose one legend names it once)."""
    names = dict.fromkeys(label for runs in panels for label, _ in _cells(runs, labels))
    return {name: k for k, name in enumerate(names)}


# A line style and marker per cell, beside its colour: curves that coincide (GrayDiff and
# RGBDiff on gray video) stay visible one over the other.
STYLES = [("-", "o"), ("--", "s"), (":", "^"), ("-.", "D"), ((0, (5, 1)), "v"), ((0, (1, 2)), "P")]


def _draw_curves(
    ax: plt.Axes, runs: pd.DataFrame, labels: list[str], x: str, y: str,
    styles: dict[str, int] | None = None,
) -> bool:  # fmt: skip
    """Mean of ``y`` against ``x`` (from each run's history.json) per cell, with a min-max band;
    False if no run has a point to draw. ``styles``: each label's colour and line style, the
    same in every panel of a figure (whose one legend names each label once; default: by order
    here). The figure puts the legend outside the panels (:func:`_legend_outside`)."""
    drawn = False
    for k, (label, group) in enumerate(_cells(runs, labels)):
        k = styles[label] if styles is not None else k
        series = [[(row[x], row[y]) for row in run_history(r) if y in row] for r in group["record"]]
        series = [s for s in series if s]
        if not series:
            continue
        n = min(len(s) for s in series)
        xs = np.array([p[0] for p in series[0][:n]])
        ys = np.array([[p[1] for p in s[:n]] for s in series])  # (runs, points)
        line, marker = STYLES[k % len(STYLES)]
        ax.plot(xs, ys.mean(0), linestyle=line, marker=marker, markevery=max(1, n // 8),
                markersize=4, color=f"C{k % 10}", label=label)  # fmt: skip
        ax.fill_between(xs, ys.min(0), ys.max(0), color=f"C{k % 10}", alpha=0.15)
        drawn = True
    return drawn


def _legend_outside(fig: plt.Figure, axes: list[plt.Axes]) -> None:
    """One legend for the whole figure, below its panels: the figure grows by its height."""
    handles: dict[str, Any] = {}
    for ax in axes:
        for handle, name in zip(*ax.get_legend_handles_labels(), strict=True):
            handles.setdefault(name, handle)
    if not handles:
        fig.tight_layout()
        return
    ncol = max(1, min(len(handles), int(fig.get_figwidth() // 2.6)))
    height = 0.25 + 0.2 * -(-len(handles) // ncol)  # inches: a row of entries each
    fig.set_figheight(fig.get_figheight() + height)
    fig.legend(handles.values(), handles.keys(), loc="lower center", ncol=ncol, fontsize=8,
               frameon=False)  # fmt: skip
    fig.tight_layout(rect=(0, height / fig.get_figheight(), 1, 1))


MAX_PANELS_A_ROW = 3
MAX_FIGURE_WIDTH = 20.0  # inches: 2,200 px at the figures' 110 dpi


def _curve_panels(
    runs: pd.DataFrame,
    panel: str,
    labels: list[str],
    x: str,
    y: str,
    title: str,
    xlabel: str,
    ylabel: str,
) -> plt.Figure | None:
    """One panel per value of ``panel`` (a data set, a backbone), curves per cell in each."""
    panels = sorted(runs[panel].dropna().unique())
    if not panels:  # records that lack what the panels are by (no data part): listed, not drawn
        return None
    cols = min(len(panels), MAX_PANELS_A_ROW)  # a grid, so that many panels stay readable
    rows = -(-len(panels) // cols)
    fig, grid = plt.subplots(rows, cols, figsize=(4.5 * cols, 3.5 * rows), squeeze=False)
    axes = list(grid.flat[: len(panels)])
    for spare in grid.flat[len(panels) :]:
        fig.delaxes(spare)
    styles = label_styles([runs[runs[panel] == p] for p in panels], labels)
    drawn = [
        _draw_curves(ax, runs[runs[panel] == p], labels, x, y, styles)
        for ax, p in zip(axes, panels, strict=True)
    ]
    for ax, name, ok in zip(axes, panels, drawn, strict=True):
        ax.set(title=name if ok else f"{name}: nothing to draw yet", xlabel=xlabel, ylabel=ylabel)
    if not any(drawn):
        plt.close(fig)
        return None
    fig.suptitle(title, fontsize=10)
    _legend_outside(fig, axes)
    return fig


def fig5_atari_curves(runs: pd.DataFrame, published: dict[str, Any]) -> tuple[pd.DataFrame, Draw]:
    """Per game: the training score (top, beside the game's random play) and the fraction of
    the fully connected layer's units that are dead (bottom, ``dead/embed.2``: core none or
    lstm, Table 1's; the convolutions' stay at 0 in every committed run), mean and min-max band
    over seeds, per input."""
    done = atari_runs(runs)  # labelled by input, and by budget where there are several

    def draw() -> plt.Figure | None:
        games = sorted(done["game"].dropna().unique())
        if not games:  # records from before the game was recorded: listed under Table 1
            return None
        width = min(4.5, MAX_FIGURE_WIDTH / len(games))  # six games stay within a page
        fig, axes = plt.subplots(2, len(games), figsize=(width * len(games), 6), squeeze=False)
        drawn = []
        styles = label_styles([done[done["game"] == game] for game in games], ["label"])
        for k, game in enumerate(games):
            runs_of_game = done[done["game"] == game]
            drawn.append(_draw_curves(
                axes[0, k], runs_of_game, ["label"], "env_steps", "train/score", styles
            ))  # fmt: skip
            fc = _draw_curves(axes[1, k], runs_of_game, ["label"], "env_steps", "dead/embed.2",
                              styles)  # fmt: skip
            if not fc:  # a core without the FC layer (ftlstm), or another's name for it
                axes[1, k].set_title("no dead/embed.2 in these runs' histories", fontsize=8)
            random_play = lookup(published, "atari_reference_scores", game, "random")
            if random_play is not None:
                axes[0, k].axhline(random_play, color="0.4", ls=":", lw=1, label="random play")
            axes[0, k].set(title=game, xlabel="env steps", ylabel="mean score, last 20 episodes")
            axes[1, k].set(xlabel="env steps", ylabel="FC units dead (fraction)",
                           ylim=(-0.02, 1.02))  # fmt: skip
        if not any(drawn):
            plt.close(fig)
            return None
        fig.suptitle("Figure 5: training score and dead FC units, FDR vs FDR+EDR", fontsize=10)
        _legend_outside(fig, list(axes.flat))
        return fig

    return done, draw


def fig10_kth_curves(runs: pd.DataFrame) -> tuple[pd.DataFrame, Draw]:
    """A panel per data set (generated, real clips split in time), a curve per cell."""
    done = labelled(finished(runs, "kth", without_ablations))
    return done, lambda: _curve_panels(
        done, "data.label", ["choices.backbone", "input", "scale"], "epoch", "eval/accuracy",
        "Figure 10: KTH test accuracy during training", "epoch", "test video accuracy",
    )  # fmt: skip


LEARNABLE_PANELS = {"edr/tau_0": "half-life (frames)", "edr/beta_0": "beta", "edr/nu_on_0": "nu_on",
                    "edr/grad_norm": "EDR layer's gradient norm"}  # fmt: skip


def learnable_edr_curves(runs: pd.DataFrame) -> tuple[pd.DataFrame, Draw]:
    """A learnable EDR's half-life, beta and nu_on after each epoch, and its gradient's norm
    (the epoch's mean), per parameterisation: mean and min-max band over seeds."""
    done = learnable_runs(runs)
    done = done[done["choices.ablation"].str.startswith("learnable")] if not done.empty else done

    def draw() -> plt.Figure | None:
        fig, axes = plt.subplots(1, len(LEARNABLE_PANELS), figsize=(16, 4.2))
        labels = ["data.source", "choices.ablation", "scale"]
        drawn = [
            _draw_curves(ax, done, labels, "epoch", key)
            for ax, key in zip(axes, LEARNABLE_PANELS, strict=True)
        ]
        if not any(drawn):
            plt.close(fig)
            return None
        for ax, label in zip(axes, LEARNABLE_PANELS.values(), strict=True):
            ax.set(xlabel="epoch", ylabel=label)
        axes[-1].set_yscale("log")
        fig.suptitle("Learnable EDR trained with LeNet + FT-RCN: its values and gradient per epoch",
                     fontsize=10)  # fmt: skip
        _legend_outside(fig, list(axes))
        return fig

    return done, draw


def _cell_means(
    done: pd.DataFrame, prefix: str, labels: list[str]
) -> tuple[list[str], list[tuple[str, np.ndarray]]]:
    """(the names after ``prefix`` of the metrics these runs have, per cell its label and the
    mean of each of those metrics over its runs)."""
    columns = [c for c in done.columns if c.startswith(prefix) and done[c].notna().any()]
    means = [
        (label, group[columns].apply(pd.to_numeric, errors="coerce").mean().to_numpy())
        for label, group in _cells(done, labels)
    ]
    return [c.removeprefix(prefix) for c in columns], means


def _per_class(done: pd.DataFrame) -> plt.Figure | None:
    """Heat maps, one per data set (its classes differ): a row per cell, a column per class,
    each square the mean accuracy over the cell's runs, written in it."""
    labels = ["choices.representation", "choices.ablation", "scale"]
    sources = done["data.source"] if "data.source" in done else pd.Series("", index=done.index)
    panels = []
    for source, runs in done.groupby(sources.fillna("unrecorded"), sort=True):
        classes, cells = _cell_means(runs, "metrics.eval/per_class/", labels)
        if classes and cells:
            counts = [len(group) for _, group in _cells(runs, labels)]
            rows = [
                f"{label.replace(' / None', '').replace(' / nan', '')} ({n} run{'s' * (n != 1)})"
                for (label, _), n in zip(cells, counts, strict=True)
            ]
            panels.append((str(source), classes, rows, np.array([m for _, m in cells])))
    if not panels:
        return None
    widths = [max(2.5, 0.6 * len(classes)) for _, classes, _, _ in panels]
    height = 0.4 * max(len(rows) for _, _, rows, _ in panels) + 2.4
    fig, axes = plt.subplots(
        1, len(panels), figsize=(sum(widths) + 3.2 * len(panels) + 1, height), squeeze=False,
        layout="constrained", gridspec_kw={"width_ratios": widths},
    )  # fmt: skip
    for ax, (source, classes, rows, values) in zip(axes[0], panels, strict=True):
        image = ax.imshow(values, cmap="viridis", vmin=0, vmax=1, aspect="auto")
        for (i, j), value in np.ndenumerate(values):
            if np.isfinite(value):
                ax.text(j, i, f"{100 * value:.0f}", ha="center", va="center", fontsize=8,
                        color="white" if value < 0.6 else "black")  # fmt: skip
        ax.set_xticks(range(len(classes)), classes, rotation=45, ha="right", fontsize=8)
        ax.set_yticks(range(len(rows)), rows, fontsize=8)
        ax.set_title(f"{source} data", fontsize=9)
    fig.colorbar(image, ax=list(axes[0]), label="accuracy, mean over runs")
    fig.suptitle("Figure 6: per-class test accuracy (%), by representation", fontsize=10)
    return fig


def fig6_ucf101_per_class(runs: pd.DataFrame) -> tuple[pd.DataFrame, Draw]:
    done = finished(runs, "ucf101")
    return done, lambda: _per_class(done)


def _confusion(done: pd.DataFrame) -> plt.Figure | None:
    cells = _cells(done, ["data.events"])
    if not cells:
        return None
    fig, axes = plt.subplots(1, len(cells), figsize=(4.5 * len(cells), 4), squeeze=False)
    for ax, (label, group) in zip(axes[0], cells, strict=True):
        files = [run_json(Path(r).parent, CONFUSION) for r in group["record"]]
        matrix = np.mean([f["matrix"] for f in files], axis=0)
        ax.imshow(matrix, cmap="Blues")
        ax.set_xticks(range(len(files[0]["classes"])), files[0]["classes"], rotation=60, fontsize=7)
        ax.set_yticks(range(len(files[0]["classes"])), files[0]["classes"], fontsize=7)
        ax.set(xlabel="predicted", ylabel="true", title=f"{label[:40]} ({len(files)} runs)")
    fig.suptitle("Figure 7b: DVS transfer, confusion matrix after fine-tuning", fontsize=9)
    fig.tight_layout()
    return fig


def fig7b_dvs_confusion(runs: pd.DataFrame) -> tuple[pd.DataFrame, Draw]:
    done = finished(runs, "dvs_transfer")
    return done, lambda: _confusion(done)


def _layer_names(layers: list[str]) -> list[str]:
    """``representation``, ``backbone.features.1``, ... -> what a reader calls them: the
    representation's output, then each ReLU of the backbone in order, its module beside."""
    names, relu = [], 0
    for layer in layers:
        if layer == "representation":
            names.append("representation\n(its output)")
        else:
            relu += 1
            names.append(f"ReLU {relu}\n({layer.removeprefix('backbone.')})")
    return names


def _sparsity(done: pd.DataFrame) -> plt.Figure | None:
    labels = ["choices.backbone", "input", "data.label", "scale"]
    layers, cells = _cell_means(done, "metrics.sparsity/", labels)
    if not layers or not cells:
        return None
    fig, ax = plt.subplots(figsize=(7, 3.8))
    for k, (label, values) in enumerate(cells):
        line, marker = STYLES[k % len(STYLES)]
        ax.plot(range(len(layers)), values, linestyle=line, marker=marker, label=label)
    ax.set_xticks(range(len(layers)), _layer_names(layers), fontsize=8)
    ax.set(title="Figure 11: how sparse each layer's output is (one clip batch)",
           xlabel="layer, from the input up", ylabel="fraction of outputs exactly 0",
           ylim=(-0.02, 1.02))  # fmt: skip
    _legend_outside(fig, [ax])
    return fig


def fig11_activation_sparsity(runs: pd.DataFrame) -> tuple[pd.DataFrame, Draw]:
    done = labelled(finished(runs, "kth", without_ablations))
    return done, lambda: _sparsity(done)


def _profile(done: pd.DataFrame, published: dict[str, Any]) -> plt.Figure | None:
    from rliable import library as rly
    from rliable import plot_utils

    scores = normalised_scores(done, published)
    if not scores:
        return None
    taus = np.linspace(-0.5, 1.5, 41)
    with seeded_bootstrap():
        profiles, intervals = rly.create_performance_profile(scores, taus, reps=500)
    fig, ax = plt.subplots(figsize=(5, 3.5))
    plot_utils.plot_performance_profiles(
        profiles,
        taus,
        performance_profile_cis=intervals,
        xlabel="human-normalised score tau",
        labelsize="small",
        ax=ax,
    )
    ax.legend(list(scores), fontsize=7)
    ax.set_title("Performance profile, FDR vs FDR+EDR (beyond the paper)", fontsize=9)
    fig.tight_layout()
    return fig


def atari_performance_profile(
    runs: pd.DataFrame, published: dict[str, Any]
) -> tuple[pd.DataFrame, Draw]:
    done = atari_runs(runs)
    return done, lambda: _profile(done, published)


def _fig5_paper(runs: pd.DataFrame, published: dict[str, Any]) -> list[str]:
    """The paper's numbers for the games Figure 5 draws (Pong's steps to 18, Centipede's
    rewards), with their source and inconsistencies; none for a game it does not draw."""
    figure = published.get("figure5_atari") or {}
    games = set(runs["game"].dropna()) if "game" in runs else set()
    steps = figure.get("pong_env_steps_to_18") or {}
    best = figure.get("centipede_best_reward") or {}
    lines = []
    if "Pong" in games and steps.get("fdr") and steps.get("fdr_edr"):
        lines.append(
            f"Pong (Figure 5a): a training score of 18 after {steps['fdr_edr'] / 1e6:g}M env "
            f"steps with FDR+EDR, {steps['fdr'] / 1e6:g}M with FDR "
            f"({steps['fdr'] / steps['fdr_edr']:.1f}x faster)."
        )
    if "Centipede" in games and (figure.get("centipede_reward_ratio") or best):
        lines.append(
            f"Centipede (Figure 5b): FDR+EDR's training reward "
            f"{cite(figure.get('centipede_reward_ratio'), 'g')}x FDR's; later in training "
            f"FDR+EDR reaches {cite(best.get('fdr_edr'), ',.0f')} while FDR struggles to reach "
            f"{cite(best.get('fdr'), ',.0f')}."
        )
    if not lines:
        return []
    return [f"Source: {figure.get('source')}.", *lines, *(figure.get("notes") or [])]


def _fig7b_paper(runs: pd.DataFrame, published: dict[str, Any]) -> list[str]:
    """The paper's accuracy behind its Figure 7b (the matrix itself is given as a picture)."""
    accuracy = lookup(published, "appendix_a_dvs", "finetuned_accuracy")
    if accuracy is None:
        return []
    return [
        f"Source: {lookup(published, 'appendix_a_dvs', 'source')}.",
        f"Fine-tuned accuracy {cite(accuracy)} % on its DVS128 recordings of KTH clips (30 % "
        "tested); the confusion matrix's cells are given as a picture only.",
    ]


# Per figure, the lines of the paper's numbers its caption shows (from its runs: the games drawn)
PAPER_CAPTIONS: dict[str, Callable[[pd.DataFrame, dict[str, Any]], list[str]]] = {
    "figure5_atari_curves": _fig5_paper,
    "figure7b_dvs_confusion": _fig7b_paper,
}


def write_figure(
    name: str, title: str, runs: pd.DataFrame, draw: Draw, out_dir: Path,
    published: dict[str, Any] | None = None,
) -> list[Path]:  # fmt: skip
    """``<out_dir>/figures/<name>.png`` and its caption ``<name>.md``, with the paper's numbers
    for what it draws where the paper gives any (:data:`PAPER_CAPTIONS`); nothing if ``draw``
    has no data to show."""
    if runs.empty:
        return []
    fig = draw()
    if fig is None:
        return []
    png = out_dir / "figures" / f"{name}.png"
    save_figure(fig, png, dpi=110)
    paper = PAPER_CAPTIONS.get(name, lambda _runs, _published: [])(runs, published or {})
    caption = [
        f"# {title}",
        "",
        f"![{title}]({png.name})",
        "",
        *provenance(runs),
        *(paper_heading(published or {}, paper) if paper else []),
        "",
        "Records:",
        "",
    ]
    caption += [f"- `{r}`" for r in runs["record"]]
    return [png, write_text_atomic(png.with_suffix(".md"), "\n".join(caption) + "\n")]


def copy_pixel_response(runs: pd.DataFrame, out_dir: Path) -> list[Path]:
    """Figure 3b: the newest representation-demo run's picture of one pixel over time."""
    done = finished(runs, "representation_demo")
    if done.empty:
        return []
    newest = done.iloc[[-1]]
    source = run_file(Path(newest["record"].iloc[0]).parent, PIXEL_RESPONSE)  # checked on load
    png = out_dir / "figures" / "figure3b_pixel_response.png"
    with atomic_path(png) as tmp:
        shutil.copyfile(source, tmp)
    title = "Figure 3b: one pixel's response to every representation (task=representation_demo)"
    caption = [
        f"# {title}",
        "",
        f"![{title}]({png.name})",
        "",
        *provenance(newest),
        "",
        f"Record: `{newest['record'].iloc[0]}`",
    ]
    return [png, write_text_atomic(png.with_suffix(".md"), "\n".join(caption) + "\n")]
