"""``make demo`` prints, beside its one-seed table, the committed seeds' range and 3-seed means:
those lines (Makefile, README) must be what the records in results/learning/kth_demo hold. They
once cited records of older code while the demo's own run gave another number."""

from __future__ import annotations

import json
import statistics
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DEMO_RECORDS = ROOT / "results" / "learning" / "kth_demo"


def _accuracies(representation: str) -> list[float]:
    """The standardised demo runs' accuracies (%) of ``representation``, seeds 0-2."""
    found = {}
    for path in DEMO_RECORDS.glob(
        f"experiment=kth_demo,representation={representation},seed=*/run.json"
    ):
        record = json.loads(path.read_text())
        if record["config"]["task"].get("normalize_input") and record["status"] == "finished":
            found[record["seed"]] = 100 * record["metrics"]["eval/accuracy"]
    assert sorted(found) == [0, 1, 2], (representation, sorted(found))
    return [found[seed] for seed in (0, 1, 2)]


def test_the_demos_lines_are_what_the_committed_records_hold() -> None:
    edr, fdr = _accuracies("edr"), _accuracies("fdr")
    makefile = (ROOT / "Makefile").read_text()
    spread = (f"FDR alone scored {min(fdr):.1f} to {max(fdr):.1f} % and EDR {min(edr):.1f} to "
              f"{max(edr):.1f} %")  # fmt: skip
    means = (f"EDR {statistics.mean(edr):.1f} ± {statistics.stdev(edr):.1f} % and FDR "
             f"{statistics.mean(fdr):.1f} ± {statistics.stdev(fdr):.1f} %")  # fmt: skip
    assert spread in makefile and means in makefile, (spread, means)
    assert means in " ".join((ROOT / "README.md").read_text().split())
