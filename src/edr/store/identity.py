"""What makes two runs the same run: the fingerprint of what the task receives (its resolved
node) and the seed, minus what cannot change a result (where files go, threads, loggers, resume
flags). A group the task does not read (``optimizer`` for Atari) is not part of it. A path under
one of the suite's roots (``paths.*``) enters it as ``<paths.real_video>/kth``, not as this
machine's folder, so a setting has one identity on every checkout. A sweep maps each cell to a
folder named from the job's own overrides, minus the same keys, so that the same command finds
the same folders again.
"""

from __future__ import annotations

import copy
import hashlib
import json
import logging
import re
from collections.abc import Iterable, Mapping
from typing import Any

from omegaconf import DictConfig, OmegaConf

# Keys (the last part of a dotted key) that never change a result.
NON_SEMANTIC = frozenset(
    {
        "out_dir",  # where the run writes
        "cache_dir",  # where decoded frames are kept
        "threads",  # CPU threads
        "resume",  # whether a run continues its checkpoint
        "logger",  # where scalars are logged
        "log_every",  # how often scalars are logged
        "checkpoint_every",  # how often a checkpoint is written
        "num_workers",  # DataLoader worker processes
        "device",  # cpu or cuda: the machine is recorded separately
    }
)
# Whole sections that never change a result.
NON_SEMANTIC_SECTIONS = frozenset({"hydra", "paths"})
# The top-level keys a run's result depends on: the task gets everything else it reads (a
# representation, a backbone, an optimizer) through interpolations into its own node.
IDENTITY_KEYS = ("seed", "task")
# Groups whose files write into another section (``# @package representation``).
PACKAGED_INTO = {"ablation": "representation"}
# Arguments added after runs were recorded, per class or function (a node's ``_target_``), with
# the value those runs had: at that value the key stays out of the fingerprint wherever a node of
# that target sits (EDR: task.representation, task.env.edr, task.representations.*), so adding
# a setting to the config with its default keeps old runs' identities.
ADDED_DEFAULTS: dict[str, dict[str, Any]] = {
    "edr.rl.settings.NetworkSettings": {"input_norm": "raw", "precision": "float32"},
    "edr.rl.settings.EvalSettings": {"policy": "sample"},
    "edr.rl.settings.OptimSettings": {"lr_warmup_env_steps": 0},
    "edr.rl.settings.LossSettings": {"advantage": "raw"},
    "edr.data.datasets.kth": {"actions": None, "folds": 2, "sequences": None},
    "edr.data.datasets.ucf101": {"lists": None, "subset": False},
    "edr.tasks.recognition.train_recognition": {"normalize_input": False, "frame_control": None},
    "edr.representations.EDR": {
        "parameterization": "log",
        "bptt_window": None,
        "out_dtype": "float32",
    },
}
MAX_DIRNAME = 120  # longer job folder names end in a digest
log = logging.getLogger(__name__)


def semantic_config(config: Mapping[str, Any]) -> dict[str, Any]:
    """``config`` (a resolved, plain dict) without the keys that cannot change a result."""

    def strip(node: Any) -> Any:
        if isinstance(node, Mapping):
            return {k: strip(v) for k, v in node.items() if k not in NON_SEMANTIC}
        if isinstance(node, list | tuple):
            return [strip(v) for v in node]
        return node

    return {k: strip(v) for k, v in config.items() if k not in NON_SEMANTIC_SECTIONS | NON_SEMANTIC}


def digest(payload: Any, length: int = 16) -> str:
    """A stable hex digest of a JSON-able value (dict keys in sorted order)."""
    text = json.dumps(payload, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:length]


def without_added_defaults(node: Any) -> Any:
    """``node`` without the arguments of :data:`ADDED_DEFAULTS` that hold their old value, in
    every node it holds that builds their target (in place)."""
    if isinstance(node, dict):
        for key, old in ADDED_DEFAULTS.get(node.get("_target_"), {}).items():
            if key in node and node[key] == old:
                del node[key]
        for value in node.values():
            without_added_defaults(value)
    elif isinstance(node, list):
        for value in node:
            without_added_defaults(value)
    return node


def root_symbol(name: str) -> str:
    """How a suite root stands in an identity or a record: ``<paths.results>``."""
    return f"<paths.{name}>"


def symbolic_roots(cfg: DictConfig) -> DictConfig:
    """A copy of ``cfg`` whose ``paths.*`` roots are their symbols, so that what interpolates
    them (``task.data_root: ${paths.real_video}/kth``) resolves to ``<paths.real_video>/kth``."""
    symbolic = copy.deepcopy(cfg)
    for name in symbolic.get("paths") or {}:
        symbolic.paths[name] = root_symbol(str(name))
    return symbolic


def with_root_symbols(node: Any, roots: Mapping[str, str]) -> Any:
    """``node`` (JSON-like) with every absolute path under one of ``roots`` (name -> folder)
    written from that root's symbol, the innermost root first, also inside a sentence:
    ``/home/me/edr/results/cache/x`` -> ``<paths.results>/cache/x``."""
    # absolute folders only: a root already written as its symbol (a record's own) is none
    symbols = {str(root): root_symbol(name) for name, root in roots.items() if str(root)[:1] == "/"}
    if not symbols:
        return node
    # a root where a path starts (not inside another name) and up to where its own name ends
    alternatives = "|".join(map(re.escape, sorted(symbols, key=len, reverse=True)))
    pattern = re.compile(rf"(?<![^\s'\"(=:])({alternatives})(?=/|$|[\s'\"),;])")

    def write(value: Any) -> Any:
        if isinstance(value, str):
            return pattern.sub(lambda found: symbols[found.group(1)], value)
        if isinstance(value, Mapping):
            return {key: write(v) for key, v in value.items()}
        if isinstance(value, list | tuple):
            return [write(v) for v in value]
        return value

    return write(node)


def _identity_config(cfg: DictConfig) -> dict[str, Any]:
    resolved = OmegaConf.to_container(symbolic_roots(cfg), resolve=True)
    return without_added_defaults(semantic_config({k: resolved.get(k) for k in IDENTITY_KEYS}))


def run_identity(cfg: DictConfig) -> tuple[dict[str, Any], str, str]:
    """(semantic config, fingerprint, cell): the seed and the task's resolved node, minus what
    cannot change a result and with the suite's roots as symbols; the cell is the fingerprint with the seed taken out everywhere it is
    used (``${seed}`` interpolations too), so seeds of one cell share it."""
    semantic = _identity_config(cfg)
    unseeded = copy.deepcopy(cfg)
    unseeded.seed = None
    return semantic, digest(semantic), digest(_identity_config(unseeded))


def sections_read(task: DictConfig) -> set[str]:
    """The top-level sections (``representation``, ``backbone``, ...) that the task's node
    reads through an interpolation such as ``${representation}``."""
    text = OmegaConf.to_yaml(task, resolve=False)
    return set(re.findall(r"\$\{([A-Za-z_]\w*)", text))


def ignored_overrides(cfg: DictConfig, overrides: Iterable[str]) -> list[str]:
    """The overrides that set a top-level section the task does not read (the demo's
    ``representation=edr_k3``): they change nothing in its result."""
    read = sections_read(cfg.task) | set(IDENTITY_KEYS)

    def section(override: str) -> str:
        first = override_key(override).split(".")[0]
        return PACKAGED_INTO.get(first, first)

    return [
        o
        for o in overrides
        if is_semantic_override(o)
        and section(o) not in read
        and isinstance(cfg.get(section(o)), DictConfig)
    ]


def flatten(node: Any, prefix: str = "") -> dict[str, Any]:
    """Nested dicts -> {"a.b.c": leaf}; lists stay leaves."""
    if not isinstance(node, Mapping):
        return {prefix: node}
    flat: dict[str, Any] = {}
    for key, value in node.items():
        flat.update(flatten(value, f"{prefix}.{key}" if prefix else str(key)))
    return flat


def config_diff(old: Mapping[str, Any], new: Mapping[str, Any]) -> list[str]:
    """The keys whose values differ, as ``key: old -> new`` (``<absent>`` where one lacks it)."""
    a, b = flatten(old), flatten(new)
    missing = "<absent>"
    return [
        f"{key}: {a.get(key, missing)!r} -> {b.get(key, missing)!r}"
        for key in sorted(a.keys() | b.keys())
        if a.get(key, missing) != b.get(key, missing)
    ]


def override_key(override: str) -> str:
    """``+task.x=1`` -> ``task.x``."""
    return override.split("=", 1)[0].lstrip("+~")


def is_semantic_override(override: str) -> bool:
    parts = override_key(override).split(".")
    return parts[0] not in NON_SEMANTIC_SECTIONS and parts[-1] not in NON_SEMANTIC


def job_dirname(overrides: Iterable[str]) -> str:
    """A folder name for a job from its command-line overrides: the semantic ones, sorted by key,
    ``key=value`` joined by commas, path separators replaced; ``defaults`` when there are none."""
    kept = sorted((o.lstrip("+") for o in overrides if is_semantic_override(o)), key=override_key)
    name = re.sub(r"[/\\\s]+", "_", ",".join(kept)) or "defaults"
    if len(name) > MAX_DIRNAME:
        name = f"{name[: MAX_DIRNAME - 17]}_{digest(name)}"
    return name


def warn_ignored(cfg: DictConfig, overrides: Iterable[str]) -> None:
    """Log a warning naming the overrides the task does not read, and what it reads instead."""
    if ignored := ignored_overrides(cfg, overrides):
        read = sorted(sections_read(cfg.task) - set(IDENTITY_KEYS)) or ["none"]
        log.warning(
            "warning: %s: not read by this task (it reads the task.* keys and these sections: %s), "
            "so they change nothing in its results",
            " ".join(ignored),
            ", ".join(read),
        )
