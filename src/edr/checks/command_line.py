"""The command line's overrides, checked before Hydra composes them or makes a run folder.

A key that does not exist is refused in one line naming the nearest real one, whether it was
typed plainly (Hydra: "not in struct", several lines) or with ``+`` (Hydra adds it silently,
and the run goes on in a folder named after the typo). A ``+`` addition is legal inside a node
that builds an object, where it names one of that object's arguments
(``+backbone.head.kernel=5``); nowhere else.
"""

from __future__ import annotations

import difflib
import inspect
import re
import shutil
import subprocess
from collections.abc import Callable, Sequence
from pathlib import Path

from hydra import compose, initialize_config_dir
from hydra._internal.utils import get_args_parser
from hydra.core.hydra_config import HydraConfig
from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.core.override_parser.types import Override
from hydra.errors import HydraException
from hydra.utils import get_object
from omegaconf import DictConfig, ListConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException

from edr.checks.config import ConfigError


def _first_values(overrides: Sequence[Override]) -> list[str]:
    """Each override as ``key=value`` with a sweep's first value: one job of the sweep."""
    lines = []
    for override in overrides:
        if override.is_delete():
            lines.append(override.input_line)
        elif override.is_sweep_override():
            lines.append(f"{override.get_key_element()}={next(override.sweep_string_iterator())}")
        else:
            lines.append(f"{override.get_key_element()}={override.get_value_element_as_str()}")
    return lines


def _missing(cfg: DictConfig, dotted: str, added: bool) -> tuple[str, list[str], list[str]] | None:
    """None when ``dotted`` may be set (``added``: with ``+``); else what is wrong and the names
    that would do (keys there, arguments to add). A ``+`` addition must name an argument of its parent node's target."""
    *parents, name = dotted.split(".")
    node: object = cfg
    for part in parents:
        if not isinstance(node, DictConfig):
            return None  # inside a value (a list, a string): Hydra's own check
        if part not in node:
            return f"no such key {part}", [str(k) for k in node], []
        node = node[part]
    if not isinstance(node, DictConfig):
        return None
    keys = [str(k) for k in node if not str(k).startswith("_")]
    if added and name in node:
        return f"{name} is a key already", keys, []
    if not added:
        return None if name in node else (f"no such key {name}", keys, [])
    if "_target_" not in node:
        return f"no such key {name}, and only an object's argument can be added", keys, []
    target = get_object(node["_target_"])
    parameters = inspect.signature(target).parameters
    if name in parameters or any(p.kind is p.VAR_KEYWORD for p in parameters.values()):
        return None
    owner = getattr(target, "__name__", str(target))
    return f"{owner} takes no argument {name}", keys, list(parameters)


def _refuse_twice_given(overrides: Sequence[Override]) -> None:
    """One line for a key or group given twice (``task=kth task=atari``): which one would win
    is not what the command says."""
    seen: dict[str, str] = {}
    for override in overrides:
        key = override.key_or_group
        if key in seen and not override.is_delete():
            raise ConfigError(
                f"{key} is given twice ({seen[key]} and {override.input_line}): give it once"
                + (" (a sweep over both: " + f"{key}={seen[key].split('=', 1)[1]},"
                   + f"{override.input_line.split('=', 1)[1]} with -m)" if "=" in seen[key] else "")
            )  # fmt: skip
        seen[key] = override.input_line


def _refuse_sweep_without_m(overrides: Sequence[Override], groups: Sequence[str]) -> None:
    """One line for several values (``task=kth,atari``) without ``-m``: a sweep, which only a
    multirun runs (Hydra: "Ambiguous value", several lines, exit 1)."""
    for override in overrides:
        if override.is_sweep_override():
            key = override.key_or_group
            a_list = "" if key in groups else f"; a list is written {key}=[...]"
            raise ConfigError(
                f"{override.input_line}: several values are a sweep, which needs -m "
                f"(edr-run -m {override.input_line} ...){a_list}"
            )


SLURM_HELP = (
    "run the sweep on a Slurm cluster's login node, or start a one-node cluster on this "
    "machine with sweeps/slurm-local.sh start (docs/runs.md, On Slurm)"
)


def _check_slurm_answers() -> None:
    """One line when ``hydra/launcher=slurm`` has no cluster to submit to: no ``srun`` or
    ``sbatch`` on the PATH, or a controller that does not answer ``sinfo`` (10 s)."""
    missing = [tool for tool in ("srun", "sbatch", "sinfo") if shutil.which(tool) is None]
    if missing:
        raise ConfigError(
            f"hydra/launcher=slurm: no {', '.join(missing)} on the PATH: {SLURM_HELP}"
        )
    try:
        answer = subprocess.run(["sinfo", "-h"], capture_output=True, text=True, timeout=10)
    except subprocess.TimeoutExpired:
        raise ConfigError(
            f"hydra/launcher=slurm: the Slurm controller did not answer sinfo in 10 s: {SLURM_HELP}"
        ) from None
    if answer.returncode != 0:
        said = " ".join(answer.stderr.split())[:200] or f"exit status {answer.returncode}"
        raise ConfigError(f"hydra/launcher=slurm: sinfo failed ({said}): {SLURM_HELP}")


def check_command_line(
    argv: Sequence[str], conf_dir: str | Path, check: Callable[[DictConfig], None]
) -> None:
    """:class:`ConfigError` in one line for the first override of ``argv`` that names no real key
    or option, then ``check`` on the config composed (a sweep: with each value's first choice)."""
    args, _ = get_args_parser().parse_known_args(list(argv))
    if args.shell_completion or args.help or args.hydra_help or args.info:
        return
    if args.config_name or args.config_path or args.config_dir:
        return  # another config than ours: Hydra checks it
    try:
        parsed = OverridesParser.create().parse_overrides(args.overrides)
    except HydraException as error:
        raise ConfigError(" ".join(str(error).split())) from None
    ours = [o for o in parsed if not o.key_or_group.startswith("hydra")]
    _refuse_twice_given(ours)
    groups = sorted(p.name for p in Path(conf_dir).iterdir() if p.is_dir())
    if not args.multirun:
        _refuse_sweep_without_m(parsed, groups)
    if args.multirun and any(
        o.key_or_group == "hydra/launcher" and o.get_value_element_as_str() == "slurm"
        for o in parsed
    ):
        _check_slurm_answers()
    chosen = [o for o in ours if o.key_or_group in groups]
    _refuse_deleted_group(chosen, Path(conf_dir))
    cfg = None
    try:
        cfg = _composed(ours, chosen, groups, Path(conf_dir))
        HydraConfig.instance().set_config(cfg)  # ${hydra:...} resolves as in the run
        _resolve_all(cfg)
        check(cfg)
    except HydraException as error:  # a composition that fails (a deleted group's interpolation)
        raise ConfigError(" ".join(str(error).split())) from None
    except OmegaConfBaseException as error:  # a value that does not resolve (an unset variable)
        raise ConfigError(_unresolved(error, cfg)) from None


def _composed(
    ours: list[Override], chosen: list[Override], groups: list[str], conf_dir: Path
) -> DictConfig:
    """The config the command composes (a sweep: its first job's), once every override names a
    real option or key."""
    with initialize_config_dir(config_dir=str(conf_dir), version_base="1.3"):
        for override in chosen:  # an option that does not exist
            options = sorted(
                f.stem for f in (Path(conf_dir) / override.key_or_group).glob("*.yaml")
            )
            values = list(override.sweep_string_iterator()) if override.is_sweep_override() else [
                override.get_value_element_as_str()]  # fmt: skip
            for value in values:
                if value not in (*options, "null"):
                    raise ConfigError(
                        f"{override.key_or_group}={value}: no such option{_nearest(value, options)}; "
                        f"the options: {', '.join(options)}"
                    )
        base = compose("config", overrides=_first_values(chosen), return_hydra_config=True)
        task = base.hydra.runtime.choices.get("task")
        keys_given = {o.key_or_group for o in chosen}
        for override in ours:
            key = override.key_or_group
            if key in groups or override.is_delete():
                continue
            if override.is_force_add() and _missing(base, key, added=False) is None:
                continue  # ++ on a key that exists: a plain change
            if missing := _missing(base, key, override.is_add() or override.is_force_add()):
                raise ConfigError(_refusal(override, missing, task, given="task" in keys_given))
        return compose("config", overrides=_first_values(ours), return_hydra_config=True)


def _refuse_deleted_group(chosen: Sequence[Override], conf_dir: Path) -> None:
    """One line for ``~task`` (or another group the config picks an option of): every run needs
    one; only a group that is off by default (``~ablation``, ``~game``) may be deleted."""
    primary = OmegaConf.to_container(OmegaConf.load(conf_dir / "config.yaml"), resolve=False)
    picked = {}
    for entry in primary.get("defaults", []):
        if isinstance(entry, dict):
            picked.update(entry)
    for override in chosen:
        group = override.key_or_group
        if override.is_delete() and picked.get(group) is not None:
            options = sorted(f.stem for f in (conf_dir / group).glob("*.yaml"))
            raise ConfigError(
                f"{override.input_line}: a run needs its {group} (the default is "
                f"{group}={picked[group]}): pick one with {group}=... ({', '.join(options)})"
            )


def _resolve_all(cfg: DictConfig) -> None:
    """Every value but Hydra's own resolved, as the run's record will: an interpolation that
    fails (an unset environment variable, a path that loops) fails here, before any work."""
    for key in cfg:
        if key == "hydra":
            continue
        node = cfg[key]  # a plain value resolves as it is read
        if isinstance(node, DictConfig | ListConfig):
            OmegaConf.to_container(node, resolve=True)


ENV_NAME = re.compile(r"(?:oc\.env|edr\.env):([A-Za-z_][A-Za-z0-9_]*)")


def _unresolved(error: OmegaConfBaseException, cfg: DictConfig | None) -> str:
    """``threads=${oc.env:UNSET}: cannot be resolved (Environment variable 'UNSET' not found):
    set UNSET, or give a default (${oc.env:UNSET,<value>})``"""
    key = str(getattr(error, "full_key", "") or "")
    reason = str(getattr(error, "msg", error)).splitlines()[0]
    reason = re.sub(r"^\w+ raised while resolving interpolation: ", "", reason)
    raw: object = None
    if cfg is not None and key:
        raw = OmegaConf.to_container(cfg, resolve=False)
        for part in key.split("."):
            raw = raw.get(part) if isinstance(raw, dict) else None
    names = sorted(set(ENV_NAME.findall(f"{raw} {reason}")))
    remedy = (
        f"set the environment variable {', '.join(names)} to a value that works (or unset it, "
        "where the config gives a default)"
        if names
        else "give it a value, or an interpolation of a key that exists"
    )
    shown = f"{key}={raw}" if raw is not None else key or "the config"
    return f"{shown}: cannot be resolved ({reason}): {remedy}"


def _refusal(
    override: Override, missing: tuple[str, list[str], list[str]], task: str, given: bool
) -> str:
    """``task.epoch=3: no such key epoch in task=kth; did you mean task.epochs=3?``"""
    problem, keys, arguments = missing
    key = override.key_or_group
    wrong = (
        problem.split()[3].rstrip(",") if problem.startswith("no such key") else key.split(".")[-1]
    )
    where = ""
    if key.startswith("task."):
        where = f" in task={task}" + ("" if given else " (the default: pick one with task=...)")
    line = f"{override.input_line}: {problem.removesuffix(',')}{where}"
    close = difflib.get_close_matches(wrong, keys + arguments, n=1, cutoff=0.6)
    if not close:
        return line
    value = override.input_line.split("=", 1)[1] if "=" in override.input_line else ""
    plus = "" if close[0] in keys else "+"  # a key that exists is set plainly
    return f"{line}; did you mean {plus}{key.replace(wrong, close[0], 1)}={value}?"


def _nearest(word: str, choices: list[str]) -> str:
    close = difflib.get_close_matches(word, choices, n=1, cutoff=0.6)
    return f" (did you mean {close[0]}?)" if close else ""
