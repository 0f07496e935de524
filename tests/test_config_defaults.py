"""One source per default: every config group whose files build an object (``_target_``) holds,
for each key that object also defaults, the code's value, or a value :data:`CHOSEN` gives a
reason for. A setting added to the config at its default keeps old runs' fingerprints."""

from __future__ import annotations

import inspect
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from hydra.utils import get_object
from omegaconf import DictConfig, ListConfig, OmegaConf, open_dict

from edr.run import CONF_DIR
from edr.store.identity import run_identity

# The groups checked, each option composed as edr-run composes it (task=kth with its recognition
# base, edr_k3 with edr's keys), and the groups left out, with why.
GROUPS = ("representation", "backbone", "optimizer", "task")
LEFT_OUT = {
    "ablation": "one change to EDR per file, the ablation's point",
    "debug": "the smallest run of each task",
    "experiment": "a paper setting: a defaults list plus the values it chooses",
    "game": "per-game values of Table 1",
    "recognition": "composed into task/kth and task/ucf101 (base) or an experiment (demo)",
}
# Where a node's keys are another callable's arguments: a target that passes its keywords on, or
# an argument (``target.argument``) that takes a mapping of keywords.
KEYWORDS_OF = {
    "edr.tasks.recognition.train_recognition": "edr.tasks.recognition.fit_recognition",
    "edr.representations.DVSCamera": "edr.representations.dvs.DVSSimulator",
    "edr.tasks.dvs_transfer.dvs_transfer.simulator": "edr.representations.dvs.DVSSimulator",
}
# (callable, argument, the config's value): why the config departs from the code's default.
FIT = "edr.tasks.recognition.fit_recognition"  # its defaults are UCF-101's (Appendix D)
SIMULATOR = "edr.representations.dvs.DVSSimulator"  # its defaults are an ideal sensor
CHOSEN: dict[tuple[str, str, Any], str] = {
    ("torch.optim.SGD", "momentum", 0.9): "the paper says SGD; momentum chosen (torch: none)",
    ("torch.optim.SGD", "weight_decay", 0.0005): "the paper says SGD; decay chosen (torch: none)",
    ("edr.representations.EDR", "half_lives", (1.0, 3.8, 8.0)): "edr_k3: three timescales",
    ("edr.representations.EDR", "half_lives", (1.0, 3.8)): "edr_sum: the paper's two timescales",
    ("edr.representations.EDR", "combine", "sum"): "edr_sum: summed as the authors' code",
    ("edr.representations.EDR", "color", "gray"): "one ON/OFF pair per pixel: Figure 3, Table 3",
    ("edr.representations.EDR", "threshold", "hard"): "Table 3's hard EDR: events, not values",
    ("edr.representations.FDR", "color", "gray"): "Table 3's frame camera is gray, as KTH",
    (FIT, "gray", True): "KTH is gray (Table 4)",
    (FIT, "max_frames", 90): "KTH: the first 90 frames (Appendix A)",
    (FIT, "epochs", 100): "KTH: 100 epochs (Appendix A)",
    (FIT, "milestones", (60, 90)): "KTH's learning-rate drops",
    (FIT, "eval_every", 5): "KTH: 100 epochs, a test every 5",
    (SIMULATOR, "mismatch", 0.03): "DVS transfer simulates a sensor's threshold spread",
    (SIMULATOR, "shot_noise_hz", 0.1): "DVS transfer simulates a sensor's noise events",
}


def _defaults(name: str) -> dict[str, Any]:
    parameters = inspect.signature(get_object(name)).parameters.values()
    return {p.name: p.default for p in parameters if p.default is not inspect.Parameter.empty}


def _hashable(value: Any) -> Any:
    if isinstance(value, ListConfig | list | tuple):
        return tuple(_hashable(v) for v in value)
    return value


def _departures(node: DictConfig, where: str) -> Iterator[tuple[str, str, Any, Any]]:
    """(where, callable, argument, value) for each key of ``node`` and of the nodes it holds
    that sets an argument the callable also defaults, to another value. Interpolated keys
    (``${representation}``, ``${seed}``) are another group's, checked there."""
    target = node.get("_target_")
    callable_ = KEYWORDS_OF.get(target, target)
    defaults = _defaults(callable_) if callable_ else {}
    for key in node:
        if str(key).startswith("_") or OmegaConf.is_interpolation(node, key):
            continue
        value, here = node[key], f"{where}.{key}"
        if isinstance(value, DictConfig):
            keywords = KEYWORDS_OF.get(f"{target}.{key}")
            if keywords is None:
                yield from _departures(value, here)
                continue
            defaults_of_value = _defaults(keywords)
            for name, given in value.items():
                if _hashable(given) != _hashable(defaults_of_value.get(name, given)):
                    yield f"{here}.{name}", keywords, name, _hashable(given)
        elif key in defaults and _hashable(value) != _hashable(defaults[key]):
            yield here, callable_, key, _hashable(value)


def test_every_group_that_builds_an_object_is_checked_or_left_out_with_a_reason() -> None:
    builds = {
        path.parent.name
        for path in Path(CONF_DIR).glob("*/*.yaml")
        if "_target_" in path.read_text()
    }
    assert builds - set(GROUPS) - set(LEFT_OUT) == set()


def test_the_config_repeats_the_code_defaults_or_says_why_not(compose_config) -> None:
    unexplained, used = [], set()
    for group in GROUPS:
        for option in sorted(p.stem for p in (Path(CONF_DIR) / group).glob("*.yaml")):
            cfg = compose_config(f"{group}={option}")
            for where, callable_, key, value in _departures(cfg[group], f"{group}={option}"):
                if (callable_, key, value) in CHOSEN:
                    used.add((callable_, key, value))
                else:
                    unexplained.append(f"{where}: {value!r}, {callable_}'s default differs")
    assert unexplained == []
    assert set(CHOSEN) - used == set()  # no reason outlives its value


def test_edr_settings_added_at_their_defaults_keep_old_fingerprints(compose_config) -> None:
    """parameterization, bptt_window and out_dtype came into conf/representation/edr.yaml after
    runs were recorded: wherever an EDR node sits, old runs keep their identity."""
    added = ("parameterization", "bptt_window", "out_dtype")
    places = {
        "task=kth": "representation",
        "task=atari": "representation",  # task.env.edr
        "task=event_camera": "task.representations.edr_soft",
    }
    for task, node in places.items():
        today = run_identity(compose_config(task))
        cfg = compose_config(task)
        with open_dict(cfg):
            for key in added:  # as before these keys (~key cannot delete a null one)
                del OmegaConf.select(cfg, node)[key]
        assert today[1:] == run_identity(cfg)[1:], task  # fingerprint and cell
        other = run_identity(compose_config(task, f"{node}.out_dtype=float64"))
        assert other[1] != today[1], task
