"""Check a config before any work starts: every value a task, data set, representation or model
receives is checked against the type its function declares (``epochs: PositiveInt``), ranges
and choices included. Each failure is one line naming the key and what was expected.
"""

from __future__ import annotations

import dataclasses
import importlib.util
import inspect
import math
import os
import tempfile
import types
import typing
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal

from omegaconf import DictConfig, ListConfig


class ConfigError(ValueError):
    """A setting that cannot work; the message is one line naming the key."""


@dataclass(frozen=True)
class Range:
    """A finite number's allowed interval; ``open`` excludes the low end, ``open_high`` the high."""

    low: float | None = None
    high: float | None = None
    open: bool = False
    open_high: bool = False

    def problem(self, value: float) -> str | None:
        if not math.isfinite(value):
            return "a finite number"
        if self.low is not None and (value <= self.low if self.open else value < self.low):
            return f"a number {'>' if self.open else '>='} {self.low}"
        if self.high is not None and (value >= self.high if self.open_high else value > self.high):
            return f"a number {'<' if self.open_high else '<='} {self.high}"
        return None


@dataclass(frozen=True)
class Check:
    """Any other condition: ``test(value)`` returns what was expected, or None if it holds."""

    test: Callable[[Any], str | None]

    def problem(self, value: Any) -> str | None:
        return self.test(value)


PositiveInt = Annotated[int, Range(1)]
NonNegativeInt = Annotated[int, Range(0)]
PositiveFloat = Annotated[float, Range(0, open=True)]
NonNegativeFloat = Annotated[float, Range(0)]
Fraction = Annotated[float, Range(0, 1, open=True)]
BelowOne = Annotated[float, Range(0, 1, open_high=True)]  # [0, 1)
OpenFraction = Annotated[float, Range(0, 1, open=True, open_high=True)]  # (0, 1)


def _module_problem(name: Any) -> str | None:
    try:
        found = importlib.util.find_spec(name) is not None
    except (ImportError, ValueError):  # a parent package that does not exist, an empty name
        found = False
    return None if found else (
        "a module on this Python's path: no such module (install the package that holds it, "
        "or add its folder to PYTHONPATH)"
    )  # fmt: skip


ModuleName = Annotated[str, Check(_module_problem)]  # importable (not imported by the check)
Seed = Annotated[int, Range(0, 2**32 - 1)]  # what numpy's and torch's generators take


def path_problem(path: Any, below: int = 0) -> str | None:
    """What the OS refuses before any file is touched: a path or a name in it too long; with
    ``below``, a folder leaving too little room for that many levels of names under it (what
    a run writes into it: ``pretrain/checkpoint.pt``), each as long as the OS allows."""
    if str(path) == "":
        return "a path (an empty one would mean the current folder)"
    text = os.fsencode(os.path.abspath(os.path.expanduser(str(path))))  # as the OS sees it
    name_max, path_max = _path_limits()
    room = below * (name_max + 1)
    if len(text) + room >= path_max:
        return (
            f"a path shorter than {path_max - room} bytes"
            + (f" (room for {below} levels of names under it)" if below else "")
            + f"; this one has {len(text)}"
        )
    longest = max(text.split(b"/"), key=len)
    if len(longest) > name_max:
        return (
            f"a path whose every name has at most {name_max} bytes (one has {len(longest)}: "
            f"{longest[:20].decode(errors='replace')}...)"
        )
    return None


def _path_limits() -> tuple[int, int]:
    """(NAME_MAX, PATH_MAX) of the file system at /, with POSIX's usual values where unsaid."""
    try:
        return os.pathconf("/", "PC_NAME_MAX"), os.pathconf("/", "PC_PATH_MAX")
    except (AttributeError, OSError, ValueError):  # not POSIX
        return 255, 4096


def _file_in_the_way(path: Any) -> str | None:
    """Where ``path`` should be a folder: the file that stands in its place (itself or one of
    the folders above it), if any."""
    for place in (Path(str(path)).expanduser(), *Path(str(path)).expanduser().parents):
        if place.exists():
            return None if place.is_dir() else f"a folder ({place} is a file)"
    return None


def _cannot_create(path: Any) -> str | None:
    """Where a folder must be written at ``path``: why its nearest existing folder takes no new
    folder, tried with an empty one made and removed at once (``os.access`` says yes to root, on
    /proc too), or None."""
    place = Path(str(path)).expanduser().absolute()
    while not place.exists() and place != place.parent:
        place = place.parent
    try:  # named as an atomic writer's partial file: removed at a run's start if left behind
        os.rmdir(tempfile.mkdtemp(dir=place, prefix=".edr-write-check.", suffix=".partial"))
    except OSError as error:
        return f"a folder this process can write (one made in {place}: {error.strerror})"
    return None


def writable_folder_problem(path: Any, below: int = 0) -> str | None:
    """What stops a run writing into the folder ``path`` (made if missing), with room for
    ``below`` levels of names under it (:func:`path_problem`), or None."""
    return path_problem(path, below) or _file_in_the_way(path) or _cannot_create(path)


def _data_root_problem(path: Any) -> str | None:
    if path == "":
        return "a folder (an empty path is not a data set; null generates one)"
    return path_problem(path) or _file_in_the_way(path)


def _existing_dir_problem(path: Any) -> str | None:
    return _data_root_problem(path) or (
        None if Path(str(path)).expanduser().is_dir() else "an existing folder"
    )


def _existing_file_problem(path: Any) -> str | None:
    return path_problem(path) or (
        None if Path(str(path)).expanduser().is_file() else "an existing file"
    )


# A folder a run writes into, with room for a subfolder and a file in it (a cache's entries).
OutputDir = Annotated[str, Check(lambda path: writable_folder_problem(path, below=2))]
DataRoot = Annotated[str, Check(_data_root_problem)]  # its layout is checked by the data set
ExistingDir = Annotated[str, Check(_existing_dir_problem)]  # a folder a task reads
ExistingFile = Annotated[str, Check(_existing_file_problem)]  # a file a task reads


def _device_problem(name: Any) -> str | None:
    """``auto``, or a torch device this machine has (``cpu``, ``cuda``, ``cuda:1``, ``mps``)."""
    if name == "auto":
        return None
    import torch

    try:
        device = torch.device(str(name))
    except (RuntimeError, ValueError):
        return "auto, cpu, cuda or cuda:<index> (a torch device)"
    if device.type == "cpu":
        return None
    if device.type == "cuda":
        count = torch.cuda.device_count() if torch.cuda.is_available() else 0
        if count == 0:
            return "a device this machine has: it has no CUDA GPU (use auto or cpu)"
        if (device.index or 0) >= count:
            return f"a device this machine has: cuda:0 to cuda:{count - 1}"
        return None
    if device.type == "mps" and torch.backends.mps.is_available():
        return None
    return f"a device this machine has ({device.type} is not available here; use auto or cpu)"


Device = Annotated[str, Check(_device_problem)]


def torch_device(name: str) -> Any:
    """The ``torch.device`` a :data:`Device` setting names (``auto``: the GPU if there is one)."""
    import torch

    if name == "auto":
        name = "cuda" if torch.cuda.is_available() else "cpu"
    return torch.device(name)


def _cores() -> int:
    """The CPU cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


def _threads_problem(threads: Any) -> str | None:
    cores = _cores()
    if threads > cores:
        return f"at most {cores}, the CPU cores this process may run on (more threads only wait)"
    return None


Threads = Annotated[int, Range(1), Check(_threads_problem)]


# Where Linux states a container's memory limit (cgroup v2, then v1).
CGROUP_LIMITS = ("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory/memory.limit_in_bytes")
CGROUP_USAGE = ("/sys/fs/cgroup/memory.current", "/sys/fs/cgroup/memory/memory.usage_in_bytes")


def memory_bytes() -> int:
    """The memory this process may use, in bytes: the machine's, or its container's limit."""
    try:
        total = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (AttributeError, OSError, ValueError):  # not POSIX: nothing to compare against
        total = 2**63
    for limit in CGROUP_LIMITS:
        try:
            text = Path(limit).read_text().strip()
        except OSError:
            continue
        if text.isdigit():  # "max": no limit
            total = min(total, int(text))
    return total


def available_memory_bytes() -> int:
    """The memory this process can take now, in bytes: what Linux says is available
    (``MemAvailable``: free memory and caches it can drop), within what its container's limit
    leaves; the machine's memory where neither is said."""
    available = memory_bytes()
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                available = min(available, int(line.split()[1]) * 1024)
    except (OSError, ValueError, IndexError):
        pass
    for limit, used in zip(CGROUP_LIMITS, CGROUP_USAGE, strict=True):
        try:
            text, usage = Path(limit).read_text().strip(), Path(used).read_text().strip()
        except OSError:
            continue
        if text.isdigit() and usage.isdigit():
            available = min(available, max(int(text) - int(usage), 0))
    return available


@dataclass(frozen=True)
class Allocation:
    """An array a run or a benchmark holds: the values that size it, what it is, its bytes."""

    settings: str  # as the command line gives them: "task.frames=8, task.height=120"
    what: str
    nbytes: float


def check_allocations(parts: Sequence[Allocation]) -> None:
    """:class:`ConfigError` when the arrays ``parts``, held at once, take more than the memory
    available now: refused before any work, not killed by the OS (or a machine swapping) part
    way. The line names the settings of the largest. Callers pass lower bounds, so nothing that
    fits is refused."""
    total, available = sum(p.nbytes for p in parts), available_memory_bytes()
    if not parts or total <= available:
        return
    largest = max(parts, key=lambda p: p.nbytes)
    beside = f" ({total / 2**30:,.1f} GiB with everything else it holds)" if len(parts) > 1 else ""
    raise ConfigError(
        f"{largest.settings}: {largest.what} would take {largest.nbytes / 2**30:,.1f} GiB"
        f"{beside}, more than the {available / 2**30:,.1f} GiB of memory available "
        f"(of this machine's {memory_bytes() / 2**30:,.1f} GiB): use smaller values"
    )


def check_memory(settings: str, what: str, nbytes: float) -> None:
    """:func:`check_allocations` of one array, ``what``, whose size ``settings`` set."""
    check_allocations([Allocation(settings, what, nbytes)])


def _non_empty_problem(values: Any) -> str | None:
    return "a list of at least one value" if len(values) == 0 else None


NonEmpty = Check(_non_empty_problem)  # for Annotated[Sequence[...], NonEmpty]


def _repeat_problem(values: Any) -> str | None:
    twice = sorted({str(v) for v in values if list(values).count(v) > 1})
    return f"a list without repeats ({', '.join(twice)} given more than once)" if twice else None


Distinct = Check(_repeat_problem)  # for Annotated[Sequence[...], Distinct]


# A torch optimizer's arguments (its own annotations do not say their ranges).
OPTIMIZER_ARGUMENTS = {
    "lr": PositiveFloat,
    "momentum": NonNegativeFloat,
    "dampening": NonNegativeFloat,
    "weight_decay": NonNegativeFloat,
    "eps": PositiveFloat,
    "alpha": NonNegativeFloat,
}


def _plain(value: Any) -> Any:
    if isinstance(value, ListConfig):
        return list(value)
    return value


def _describe(hint: Any) -> str:
    origin = typing.get_origin(hint)
    if origin is Annotated:
        return _describe(typing.get_args(hint)[0])
    if hint is type(None):
        return "null"
    if origin is Literal:
        return "one of " + ", ".join(repr(a) for a in typing.get_args(hint))
    if origin in (typing.Union, types.UnionType):
        return " or ".join(_describe(a) for a in typing.get_args(hint))
    if origin in (list, tuple, Sequence) or hint in (list, tuple):
        return "a list"
    names = {int: "an integer", float: "a number", bool: "true or false", str: "a string"}
    return names.get(hint, getattr(hint, "__name__", str(hint)))


def _is_list_hint(hint: Any) -> bool:
    if typing.get_origin(hint) is Annotated:
        hint = typing.get_args(hint)[0]
    return typing.get_origin(hint) in (list, tuple, Sequence) or hint in (list, tuple)


def mismatch(value: Any, hint: Any) -> str | None:
    """What ``value`` should have been to match ``hint``, or None if it matches."""
    value = _plain(value)
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin is Annotated:
        inner = mismatch(value, args[0])
        if inner:
            return inner
        for rule in args[1:]:
            if isinstance(rule, Range | Check) and (found := rule.problem(value)):
                return found
        return None
    if hint is Any or isinstance(hint, typing.TypeVar):
        return None
    if hint is type(None):
        return None if value is None else "null"
    if origin in (typing.Union, types.UnionType):
        arms = [a for a in args if value is None or a is not type(None)]
        results = [mismatch(value, a) for a in arms]
        if any(r is None for r in results):
            return None
        # Say what the arm of the value's own kind (a list, or a single value) expected.
        same_kind = [r for a, r in zip(arms, results, strict=True)
                     if _is_list_hint(a) == isinstance(value, list | tuple)]  # fmt: skip
        return " or ".join(dict.fromkeys(same_kind or results))
    if origin is Literal:
        return None if value in args else _describe(hint)
    if hint is bool:
        return None if isinstance(value, bool) else _describe(hint)
    if hint is int:
        return None if isinstance(value, int) and not isinstance(value, bool) else _describe(hint)
    if hint is float:
        ok = isinstance(value, int | float) and not isinstance(value, bool)
        return None if ok else _describe(hint)
    if hint is str:
        return None if isinstance(value, str) else _describe(hint)
    if origin in (list, tuple, Sequence) or hint in (list, tuple):
        if not isinstance(value, list | tuple):
            return _describe(hint)
        if origin is tuple and args and args[-1] is not Ellipsis and len(args) != len(value):
            return f"a list of {len(args)} values"
        item = args[0] if args else Any
        bad = next((m for v in value if (m := mismatch(v, item))), None)
        return f"a list whose values are each {bad}" if bad else None
    if origin in (dict, Mapping) or hint is dict:
        return None if isinstance(value, Mapping | DictConfig) else "a mapping"
    return None  # objects the config builds (a representation, a callable): checked by their node


def _hints(target: Any) -> dict[str, Any]:
    # a dataclass's fields resolve in its module (its generated __init__ has no globals of use)
    function = (
        target
        if dataclasses.is_dataclass(target)
        else target.__init__
        if inspect.isclass(target)
        else target
    )
    try:
        return typing.get_type_hints(function, include_extras=True)
    except Exception:  # a third-party target whose annotations do not resolve: not ours to check
        return {}


def check_arguments(owner: object, values: Mapping[str, Any]) -> None:
    """``ValueError`` naming the first argument of ``type(owner).__init__`` whose value does not
    match its annotation: how a class checks its constructor's arguments (pass ``locals()``)."""
    cls = type(owner)
    hints = _hints(cls)
    for name, value in values.items():
        if name in hints and (expected := mismatch(value, hints[name])):
            raise ValueError(f"{cls.__name__}: {name}={_plain(value)!r}: expected {expected}")


def check_node(node: DictConfig, where: str) -> None:
    """Check every value of a ``_target_`` node (and the nodes inside it) against its target."""
    from hydra.utils import get_object  # only the entry point's check needs Hydra

    target = get_object(node["_target_"])
    hints = _hints(target)
    if inspect.isclass(target) and issubclass(target, _torch_optimizer()):
        hints = {**hints, **OPTIMIZER_ARGUMENTS}
    accepted = _parameters(target)
    for key, value in node.items():
        if str(key).startswith("_"):
            continue
        name = f"{where}.{key}"
        if accepted is not None and key not in accepted:
            import difflib

            near = difflib.get_close_matches(str(key), accepted, n=1)
            raise ConfigError(
                f"{name}: not a setting of {node['_target_']}"
                + (f" (did you mean {where}.{near[0]}?)" if near else "")
                + f"; it takes {', '.join(accepted) or 'none'}"
            )
        if isinstance(value, DictConfig) and "_target_" in value:
            check_node(value, name)
            continue
        if key in hints and (expected := mismatch(value, hints[key])):
            raise ConfigError(f"{name}={_plain(value)!r}: expected {expected}")
        if isinstance(value, DictConfig):  # a mapping of nodes (event_camera's representations)
            for inner, node_value in value.items():
                if isinstance(node_value, DictConfig) and "_target_" in node_value:
                    check_node(node_value, f"{name}.{inner}")
    check_together(target, node, where)


def check_together(target: Any, node: Mapping[str, Any], where: str) -> None:
    """What no single value shows, where ``target`` can say: its ``settings_problem(values)``
    (a static method, or a function's attribute) is given the node's values over the target's
    defaults and returns ``key=value: expected ...`` or None; one line naming ``where``, before
    anything is built. A data set's own :class:`ConfigError`, raised where it lists its files,
    passes through as it is (its line names the folder)."""
    settings_problem = getattr(target, "settings_problem", None)
    if settings_problem is None:
        return
    defaults = {k: p.default for k, p in inspect.signature(target).parameters.items()
                if p.default is not inspect.Parameter.empty}  # fmt: skip
    given = {str(k): _plain(v) for k, v in node.items() if not str(k).startswith("_")}
    if problem := settings_problem({**defaults, **given}):
        raise ConfigError(f"{where}.{problem}")


def _parameters(target: Any) -> list[str] | None:
    """The keyword arguments ``target`` takes; None where it takes any (``**kwargs``) or its
    signature cannot be read."""
    try:
        parameters = inspect.signature(target).parameters.values()
    except (TypeError, ValueError):
        return None
    if any(p.kind is inspect.Parameter.VAR_KEYWORD for p in parameters):
        return None
    return [p.name for p in parameters if p.kind is not inspect.Parameter.VAR_POSITIONAL]


def _torch_optimizer() -> type:
    import torch

    return torch.optim.Optimizer


def check_config(cfg: DictConfig, *, entry: Mapping[str, Any]) -> None:
    """The entry point's own keys against ``entry`` (key -> type), then the task's node."""
    for key, hint in entry.items():
        if expected := mismatch(cfg.get(key), hint):
            raise ConfigError(f"{key}={_plain(cfg.get(key))!r}: expected {expected}")
    check_node(cfg.task, "task")
