"""paper/ holds what the committed records give, and nothing else: every table whose records are
all committed (``results/learning/``, ``results/bench/``), rendered again from them, equals the
committed file word for word, captions included. A number written into paper/ by hand, or one
whose record is gone, fails here. (Table 2's accuracy and Figure 3b read the tiny sweeps, which
``make paper`` runs and nothing commits: ``tests/test_paper.py`` checks those.)"""

from __future__ import annotations

from pathlib import Path

import pytest

from edr import tables

ROOT = Path(__file__).resolve().parents[1]
FROM_COMMITTED_RECORDS = (
    "table1_atari.md", "table3_event_camera.md", "table4_kth.md", "appendix_a_dvs.md",
    "ablation_edr.md", "table2_speed.md", "atari_edr_cost.md", "flow_accuracy.md",
)  # fmt: skip


@pytest.mark.slow  # renders every committed table: about a minute
def test_every_committed_table_is_what_its_committed_records_give(tmp_path, monkeypatch) -> None:
    monkeypatch.chdir(ROOT)  # the records' paths as paper/ names them, relative to the root
    scope = [p for p in tables.COMMITTED_SCOPE if p.parts[:2] == ("results", "learning")]
    runs = [arg for folder in scope if folder.is_dir() for arg in ("--runs", str(folder))]
    tables.main([*runs, "--bench", "results/bench", "--out", str(tmp_path)])
    for name in FROM_COMMITTED_RECORDS:
        assert (tmp_path / name).read_text() == (ROOT / "paper" / name).read_text(), name
