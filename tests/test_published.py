"""The paper's numbers in ``published.yaml`` against the paper's own tables (read from the paper's
text, ``../shared/paper/edr-paper.md``), and the Avg. gain formula as a known answer."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from edr.report.atari_gains import average_gains
from edr.report.published import load_published

PAPER = Path(__file__).resolve().parents[2] / "shared" / "paper" / "edr-paper.md"
PUBLISHED = load_published()


@pytest.fixture(scope="module")
def paper_tables() -> dict[str, list[list[str]]]:
    """Each Markdown table of the paper, by the first cell of its first row: rows of cells
    (bold marks and citations like ``[65]`` removed)."""
    if not PAPER.is_file():
        pytest.skip(f"{PAPER} is not here (it lies in ../shared beside the checkout)")
    tables: dict[str, list[list[str]]] = {}
    current: list[list[str]] = []
    for line in [*PAPER.read_text().splitlines(), ""]:
        if line.startswith("|"):
            cells = [re.sub(r"\*\*|\s*\[\d+\]", "", c).strip() for c in line.strip("|").split("|")]
            if not set("".join(cells)) <= set("-: "):
                current.append(cells)
        elif current:
            tables[current[0][0] or current[0][1]] = current
            current = []
    return tables


def _number(text: str) -> float:
    return float(text.replace("%", "").replace("K", "e3").strip())


GAMES = {"Pacman": "MsPacman"}  # the paper's name -> ALE's


def test_table1_every_game_and_input(paper_tables) -> None:
    rows = {r[0]: r for r in paper_tables["FDR"][2:] if r[0] != "Avg. gain"}
    published = PUBLISHED["table1_atari"]["games"]
    assert {GAMES.get(g, g) for g in rows} == set(published)
    for game, row in rows.items():
        ours = published[GAMES.get(game, game)]
        for offset, inputs in ((1, "fdr"), (4, "fdr_edr")):
            for k, column in enumerate(("avg", "best", "worst")):
                assert ours[inputs][column] == _number(row[offset + k]), (game, inputs, column)


def test_table1_avg_gain_row_is_recomputed_from_its_rows(paper_tables) -> None:
    """The known answer: the formula turns the paper's own rows into its +23.8 / +20.9 / +70.2."""
    (gain_row,) = [r for r in paper_tables["FDR"] if r[0] == "Avg. gain"]
    printed = {c: _number(gain_row[4 + k]) for k, c in enumerate(("avg", "best", "worst"))}
    assert printed == {"avg": 23.8, "best": 20.9, "worst": 70.2}
    assert PUBLISHED["table1_atari"]["avg_gain_percent"] == printed
    recomputed = average_gains(PUBLISHED["table1_atari"]["games"])
    assert {c: round(v, 1) for c, v in recomputed.items()} == printed


TABLE2_NAMES = {  # the paper's row (type, representation) -> our representation name
    ("Frame", "RGB"): "fdr", ("Frame Diffs", "Gray"): "graydiff", ("", "RGB"): "rgbdiff",
    ("Flow", "MPEG Flow"): "mpeg_flow", ("", "OF- Farneback"): "farneback",
    ("", "OF - TV-$L^1$"): "tvl1", ("", "OF - Brox"): "brox",
    ("EDR", "$\\tau_{1/2} = 1$ frame"): "edr_fast", ("", "$\\tau_{1/2} = 3.8$ frames"): "edr",
}  # fmt: skip


def test_table2_accuracy_and_speed_of_every_row(paper_tables) -> None:
    rows = paper_tables["Type"][1:]
    assert len(rows) == len(TABLE2_NAMES)
    for kind, name, accuracy, speed in rows:
        ours = TABLE2_NAMES[(kind, name)]
        assert PUBLISHED["table2_ucf101"]["accuracy"]["ltc"][ours] == _number(accuracy), ours
        paper_speed = None if speed == "-" else _number(speed)
        assert PUBLISHED["speed"]["fps"].get(ours) == paper_speed, ours


def test_table3_camera_rows(paper_tables) -> None:
    rows = paper_tables["Specification"][1:]
    published = PUBLISHED["table3_event_camera"]["rows"]
    assert [r["frame_camera"] for r in published] == [r[1] for r in rows]
    assert [r["event_camera"] for r in published] == [r[2] for r in rows]


def test_table4_every_backbone_and_input(paper_tables) -> None:
    rows = paper_tables["RCN Properties"][2:]
    heads = {"Long-term RCN": "lrcn", "Feature Tracking RCN": "ftrcn", "": "ftrcn"}  # see notes
    for conv, head, fdr, edr in rows:
        ours = PUBLISHED["table4_kth"]["accuracy"][f"{conv.lower()}_{heads[head]}"]
        assert (ours["fdr"], ours["edr"]) == (_number(fdr), _number(edr)), (conv, head)
    notes = " ".join(PUBLISHED["table4_kth"]["notes"])
    assert "79.6" in notes and "FT-RCN" in notes  # the paper's inconsistencies, said


def test_appendix_a_fine_tuned_accuracy() -> None:
    if not PAPER.is_file():
        pytest.skip(f"{PAPER} is not here")
    found = re.search(r"achieve a ([\d.]+)% classification accuracy", PAPER.read_text())
    assert found and PUBLISHED["appendix_a_dvs"]["finetuned_accuracy"] == float(found.group(1))


def test_figure5_numbers_from_the_papers_text() -> None:
    if not PAPER.is_file():
        pytest.skip(f"{PAPER} is not here")
    text = " ".join(PAPER.read_text().split())
    figure = PUBLISHED["figure5_atari"]
    steps = re.search(r"\(([\d.]+)M vs\. ([\d.]+)M training episodes to reach a high score of 18\)",
                      text)  # fmt: skip
    assert steps and figure["pong_env_steps_to_18"] == {
        "fdr_edr": float(steps.group(1)) * 1e6, "fdr": float(steps.group(2)) * 1e6,
    }  # fmt: skip
    ratio = re.search(r"FDR\+EDR based training reaches ([\d.]+)x higher reward", text)
    assert ratio and figure["centipede_reward_ratio"] == float(ratio.group(1))
    best = re.search(r"maximum reward of ([\d,]+) later on in training while FDR struggles to "
                     r"reach ([\d,]+)", text)  # fmt: skip
    assert best and figure["centipede_best_reward"] == {
        "fdr_edr": int(best.group(1).replace(",", "")), "fdr": int(best.group(2).replace(",", "")),
    }  # fmt: skip


def test_the_papers_edr_rows_are_representation_edr_at_its_two_half_lives() -> None:
    """published.yaml's settings of the paper's slow and fast EDR (which of our runs stand beside
    its Table 2 rows) are representation=edr's own, and ablation=tau_1's half-life."""
    import yaml

    import edr

    conf = Path(edr.__file__).resolve().parent / "conf"
    ours = yaml.safe_load((conf / "representation" / "edr.yaml").read_text())
    fast = yaml.safe_load((conf / "ablation" / "tau_1.yaml").read_text())
    rows = PUBLISHED["edr_rows"]["settings"]
    assert set(rows) == {"edr", "edr_fast"}
    for name, half_lives in (("edr", ours["half_lives"]), ("edr_fast", fast["half_lives"])):
        assert rows[name] == {key: ours[key] for key in rows[name]} | {"half_lives": half_lives}
