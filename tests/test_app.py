"""The real entry points with tiny configs: every config group composes, runs and sweeps work."""

from __future__ import annotations

import json
import statistics
from pathlib import Path

import pytest
from hydra.utils import instantiate

from edr import tables
from edr.representations import Representation
from edr.run import CONF_DIR, run
from edr.studies import bench

REPRESENTATIONS = sorted(p.stem for p in (Path(CONF_DIR) / "representation").glob("*.yaml"))


@pytest.mark.parametrize("name", REPRESENTATIONS)
def test_every_representation_config_instantiates(compose_config, name: str) -> None:
    cfg = compose_config(f"representation={name}", "out_dir=unused")
    rep = instantiate(cfg.representation)
    assert isinstance(rep, Representation)
    assert rep.out_channels(3) >= 1


def test_demo_runs_and_writes_a_record(compose_config, tmp_path) -> None:
    cfg = compose_config("debug=tiny", f"out_dir={tmp_path}")
    assert cfg.threads == 1 and cfg.task.frames == 8
    metrics = run(cfg)
    record = json.loads((tmp_path / "run.json").read_text())
    assert record["metrics"] == metrics
    assert record["config"]["task"]["frames"] == 8
    for key, name in (("figure/representations", "representations.png"),
                      ("figure/pixel", "pixel_response.png")):  # fmt: skip
        assert metrics[key] == name  # a file of the run, named from its folder
        assert (tmp_path / name).stat().st_size > 1000
    assert all(metrics[f"fps/{name}"] > 0 for name in cfg.task.representations)


@pytest.mark.slow
def test_multirun_sweep_writes_one_record_per_run(cli, tmp_path) -> None:
    """As the README writes it: no hydra.sweep.dir; the same command again skips every cell."""
    result = cli("edr-run", "-m", "debug=tiny", "seed=0,1", cwd=tmp_path)
    assert result.returncode == 0, result.stderr[-2000:]
    sweep = tmp_path / "results" / "sweeps" / "representation_demo"
    records = sorted(sweep.glob("*/run.json"))
    assert [r.parent.name for r in records] == ["debug=tiny,seed=0", "debug=tiny,seed=1"]
    seeds = {json.loads(r.read_text())["config"]["seed"] for r in records}
    assert seeds == {0, 1}
    first, second = (json.loads(r.read_text()) for r in records)
    assert first["choices"]["task"] == "representation_demo" and first["scale"] == "tiny"
    assert first["cell"] == second["cell"] and first["fingerprint"] != second["fingerprint"]
    output = result.stdout + result.stderr
    assert "0 skipped, 0 resumed, 2 ran, 0 failed" in output
    assert "representation_demo #1 finished:" in output  # a line per cell, with its job index
    again = cli("edr-run", "-m", "debug=tiny", "seed=0,1", cwd=tmp_path)
    assert again.returncode == 0, again.stderr[-2000:]
    assert "2 skipped, 0 resumed, 0 ran, 0 failed" in again.stdout + again.stderr


def test_unknown_representation_is_a_clear_error(cli, tmp_path) -> None:
    result = cli("edr-run", "representation=nope", f"hydra.run.dir={tmp_path}", cwd=tmp_path)
    assert result.returncode != 0
    assert "nope" in result.stderr and "representation" in result.stderr


@pytest.mark.slow
def test_atari_bench_pairs_rollouts_and_writes_a_record(tmp_path, capsys) -> None:
    bench.main(
        ["--atari", "1", "--steps", "3", "--repeats", "2", "--warmup", "0",
         "--train-frames", "40", "--network", "lenet_ftlstm", "--out-dir", str(tmp_path / "bench")]
    )  # fmt: skip
    paths = {p.name.split("_")[1]: p for p in (tmp_path / "bench").glob("atari_*.json")}
    assert set(paths) == {"envpool", "parallel"}  # both backends, one run
    record_path = paths["envpool"]
    record = json.loads(record_path.read_text())
    assert record["backend"] == "envpool" and record["train_fps"] > 0
    assert record["network"] == "lenet_ftlstm"  # trained with its one frame per step
    assert record["train_fps_steady"] > 0
    assert [row["name"] for row in record["rows"]] == [
        "Pong: FDR RGB, float32",
        "Pong: FDR RGB + EDR gray, float32",
    ]
    assert all(row["fps"] > 0 and row["frames"] == 3 for row in record["rows"])  # steps x envs
    assert len(record["costs"]) == 2 and record["cost"] == statistics.median(record["costs"])
    assert all(ms > 0 for ms in record["main_cpu_ms"])
    assert "EDR costs" in capsys.readouterr().out
    assert not (tmp_path / "paper").exists()  # edr-bench writes records only
    tables.main(
        [
            "--runs",
            str(tmp_path),
            "--bench",
            str(tmp_path / "bench"),
            "--out",
            str(tmp_path / "paper"),
        ]
    )
    text = (tmp_path / "paper" / "atari_edr_cost.md").read_text()
    (row,) = [line for line in text.splitlines() if record_path.name in line]
    assert row.startswith("| Pong | envpool | 1 | 1 | float32 |")
    assert f"{record['cost']:.1f} %" in row and f"{record['train_fps']:,.0f} over 40" in row
    assert f"{record['train_fps_steady']:,.0f} steady" in row and "| lenet_ftlstm |" in row
    assert record["train_fps_fdr"] > 0 and record["train_fps_fdr_steady"] > 0
    assert (
        f"(FDR: {record['train_fps_fdr']:,.0f}; {record['train_fps_fdr_steady']:,.0f} steady)"
        in row
    )


def test_a_results_folder_that_cannot_be_written_is_one_line(monkeypatch, capsys) -> None:
    """Hydra opens the run's log before the run starts; a read-only folder fails there (root,
    who runs these tests, writes anywhere: Hydra's failure is raised here as it raises it)."""
    import edr.run

    def hydra_main() -> None:
        try:
            raise PermissionError(13, "Permission denied", "/ro/results/runs/kth/x/run.log")
        except PermissionError as error:
            raise ValueError("Unable to configure handler 'file'") from error

    monkeypatch.setattr(edr.run, "main", hydra_main)
    with pytest.raises(SystemExit) as stopped:
        edr.run.cli()
    assert stopped.value.code == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert "Permission denied" in line and "run.log" in line and "EDR_RESULTS" in line


def test_edr_eval_says_what_it_does_and_refuses_a_folder_without_a_run(tmp_path, capsys) -> None:
    """edr-eval: --help names its options; a folder with no run.json is one line, exit 2."""
    from edr import evaluate

    with pytest.raises(SystemExit) as ended:
        evaluate.main(["--help"])
    assert ended.value.code == 0
    assert "--plays" in capsys.readouterr().out
    with pytest.raises(SystemExit) as ended:
        evaluate.main([str(tmp_path)])
    assert ended.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("edr-eval: ") and str(tmp_path) in err and len(err.splitlines()) == 1
    with pytest.raises(SystemExit) as ended:  # a folder that is not there: said before torch loads
        evaluate.main([str(tmp_path / "no_such_run")])
    assert ended.value.code == 2
    assert capsys.readouterr().err == (
        f"edr-eval: {tmp_path / 'no_such_run'}: no such folder: name a run folder edr-run wrote "
        "(it holds run.json)\n"
    )
