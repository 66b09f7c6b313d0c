"""What every Hydra entry point shares: the config path, ``--help`` before any heavy import,
validation before any work, the one-line error with exit code 2, seeding and the run's provenance.

Usage in an entry point::

    @hydra_entry("train", "TrainConfig")        # the schema: a class, or its name in configs
    def main(cfg: TrainConfig, raw: DictConfig) -> None: ...

Errors a user can cause, bad values and unknown fields (whether Hydra finds them while composing
or the schemas while validating), missing group options, unparsable overrides, unusable
checkpoints, unwritable output paths, print one line ``error: ...`` naming the dotted field and
what it accepts, and exit with code 2. ``--help`` prints the entry's template from
``conf/hydra/help/<name>.yaml`` without loading torch.
"""

from __future__ import annotations

import contextlib
import dataclasses
import difflib
import functools
import shutil
import subprocess
import sys
import time
import typing
import warnings
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, NoReturn, TypeVar

CONFIG_PATH = str(Path(__file__).resolve().parent / "conf")  # package data: works installed too
_TASKS = Path(__file__).resolve().parent / "tasks"  # the task folders (truckrl.tasks.task_names)

T = TypeVar("T")

_BEFORE: dict[Path, set[str]] = {}  # entries of a named run dir before Hydra wrote into it
_KEEP: dict[Path, Path] = {}  # a run dir that did not exist -> its nearest existing ancestor
_OUTPUTS = "outputs"  # the root of the default run dirs (conf/*.yaml: hydra.run.dir)
_SWEEP_ROOTS: list[tuple[Path, Path]] = []  # (where a sweep dir may appear, what existed above)
_STARTED = time.time()  # a sweep dir older than this process is not its own
_SCHEMA: list[type] = []  # the running entry's schema: error messages look fields up in it
_FROM_TASK = "_truckrl_from_task"  # marks an exception the task raised (keeps its traceback)


def workers_ignore_stop_signals(module_name: str) -> None:
    """Call at the top of an entry module: in the env workers that multiprocessing's spawn starts
    from it (they run the entry module as ``__mp_main__`` first) ignore Ctrl-C, SIGTERM and SIGUSR2.

    A Ctrl-C reaches the whole process group, SLURM signals every process of a job: the trainer
    stops on them and closes its workers; a worker killed by the same signal would print a
    traceback and stall the shutdown. Workers inherit no handlers, and a parent-side ``SIG_IGN``
    while they start would drop signals meant for the parent.
    """
    if module_name == "__mp_main__":
        import signal

        for name in ("SIGINT", "SIGTERM", "SIGUSR2"):
            if hasattr(signal, name):
                signal.signal(getattr(signal, name), signal.SIG_IGN)


def fail(message: str) -> NoReturn:
    """Print ``error: <message>`` as one line on stderr and exit with code 2."""
    sys.stdout.flush()
    print("error: " + " ".join(str(message).split()), file=sys.stderr, flush=True)
    sys.exit(2)


def run_or_fail(run: Callable[[Any], Any], args: Any) -> int:
    """Call ``run(args)``; what a user can cause (``ConfigError``, ``CheckpointError``) prints one
    line ``error: ...`` on stderr and returns 2, else 0."""
    from truckrl.config.fields import ConfigError
    from truckrl.rl.checkpoint import CheckpointError

    try:
        run(args)
    except (ConfigError, CheckpointError) as e:
        sys.stdout.flush()
        print("error: " + " ".join(str(e).split()), file=sys.stderr, flush=True)
        return 2
    return 0


def key_value_config(schema: type[T], argv: list[str], prog: str, about: str = "") -> T:
    """Parse ``KEY=VALUE`` arguments into a validated ``schema`` instance
    (:func:`truckrl.config.overrides.parse_key_values`).

    ``-h`` / ``--help`` prints ``prog``, ``about`` and the fields (name, default, unit, allowed,
    meaning) and exits 0; a malformed argument, an unknown key or a bad value prints one line
    ``error: ...`` and exits 2 (:func:`fail`).
    """
    from truckrl.config.fields import ConfigError, spec_table
    from truckrl.config.overrides import parse_key_values

    if {"-h", "--help"} & set(argv):
        rows = spec_table(schema)
        width = max(len(r[0]) for r in rows)
        lines = [f"usage: {prog} [KEY=VALUE ...]", *([about] if about else []), "", "keys:"]
        for name, default, unit, allowed, doc in rows:
            unit_text = f" [{unit}]" if unit else ""
            allowed = allowed.replace("(-inf, inf)", "any")  # a string, or a number without range
            default = default if default != "" else "''"
            lines.append(f"  {name:<{width}}  {doc}{unit_text}; {allowed}; default {default}")
        print("\n".join(lines))
        sys.exit(0)
    try:
        return parse_key_values(schema, argv)
    except ConfigError as e:
        fail(f"{e} (see {prog} --help)" if "arguments are KEY=VALUE" in str(e) else str(e))


def to_config(schema: type[T], cfg: Any) -> T:
    """The composed Hydra config (or a plain dict) as a validated ``schema`` instance."""
    from omegaconf import OmegaConf

    from truckrl.config.fields import build

    data = OmegaConf.to_container(cfg, resolve=True) if OmegaConf.is_config(cfg) else dict(cfg)
    data.pop("hydra", None)
    return build(schema, data)


def compose_config(config_name: str, schema: type[T], overrides: list[str]) -> T:
    """``conf/<config_name>.yaml`` with command-line ``overrides``, composed by Hydra as the entry
    point would and validated as ``schema`` (no run dir, no job).

    Raises:
        ConfigError: a bad value, an unknown field or group option, an unparsable override.
    """
    from hydra import compose, initialize_config_dir

    from truckrl.config.fields import ConfigError
    from truckrl.config.schemas import register

    register()
    try:
        with initialize_config_dir(config_dir=CONFIG_PATH, version_base=None):
            raw = compose(config_name, overrides=with_task_presets(list(overrides)))
    except ConfigError:
        raise
    except Exception as e:  # Hydra / OmegaConf composition errors
        why = describe_hydra_error(e)
        if why is None:
            raise
        raise ConfigError(why) from None
    return to_config(schema, raw)


def help_text(config_name: str) -> str:
    """The ``--help`` template of an entry point (``conf/hydra/help/<name>.yaml``), with
    ``{tasks}`` and ``{default_task}`` filled in from the task folders."""
    import yaml

    path = Path(CONFIG_PATH) / "hydra" / "help" / f"{config_name}.yaml"
    if not path.is_file():  # an entry point without a template: say where its fields are
        return f"python -m truckrl.{config_name} [OVERRIDE ...]\nFields: truckrl/conf/{config_name}.yaml\n"
    text = yaml.safe_load(path.read_text())["template"].rstrip() + "\n"
    tasks = "|".join(task_folders())
    return text.replace("{tasks}", tasks).replace("{default_task}", default_task())


def task_folders() -> list[str]:
    """:func:`truckrl.tasks.task_names` without importing torch (``--help`` must not)."""
    import pkgutil

    return sorted(m.name for m in pkgutil.iter_modules([str(_TASKS)]) if m.ispkg)


def default_task() -> str:
    """:data:`truckrl.tasks.config.DEFAULT_TASK`, read from its source without importing torch."""
    import re

    found = re.search(r'^DEFAULT_TASK = "([\w.]+)"', (_TASKS / "config.py").read_text(), re.M)
    if found is None:
        raise RuntimeError("truckrl/tasks/config.py defines no DEFAULT_TASK")
    return found.group(1)


def with_task_presets(argv: list[str]) -> list[str]:
    """``argv`` with every task folder's ``conf/`` (its presets: ``experiment=<task>``, its
    ``train_scenes``) on Hydra's search path after ``./conf``: the primary configs name no task,
    so they cannot list them. A user's ``hydra.searchpath=[...]`` keeps its entries, first."""
    confs = [_TASKS / name / "conf" for name in task_folders()]
    ours = [f"'file://{d.as_posix()}'" for d in confs if d.is_dir()]
    out, merged = [], False
    for a in argv:
        key, sep, value = a.partition("=")
        if sep and key.lstrip("+") == "hydra.searchpath" and value.startswith("["):
            inner = value.strip()[1:-1].strip()
            a, merged = f"{key}=[{', '.join(([inner] if inner else []) + ours)}]", True
        out.append(a)
    at = next((i for i, a in enumerate(out) if "=" in a and not a.startswith("-")), 0)
    # Hydra parses the overrides as one run of positional arguments: ours beside the first one
    # (-m a=1, a=1 --cfg job), or first where there is none (--info may take a value)
    ours = [f"hydra.searchpath=['file://conf', {', '.join(ours)}]"]
    return out if merged else [*out[:at], *ours, *out[at:]]


# the user's ./conf overlay on the search path is optional: Hydra's note on its absence is noise
warnings.filterwarnings(
    "ignore", message=r"provider=hydra\.searchpath in (main|command-line), path=conf"
)


def exit_on_help(config_name: str) -> None:
    """Print the help template of ``config_name`` and exit 0 when the command line asks for help
    (an entry module with heavy imports calls this first, so ``--help`` loads no torch)."""
    if {"-h", "--help"} & set(sys.argv[1:]):
        sys.stdout.write(help_text(config_name))
        sys.exit(0)


def plus_overrides(argv: list[str], prefix: str) -> list[str]:
    """Prefix ``+`` to every ``<prefix>FIELD=VALUE`` argument: a key added to a config's free-form
    dict field (``EvaluateConfig.env``, ``TrainConfig.train_env``), which Hydra spells
    ``+<prefix>FIELD=VALUE``. Arguments already written with ``+`` are left alone."""
    return ["+" + a if a.startswith(prefix) and "=" in a else a for a in argv]


def hydra_entry(
    config_name: str,
    schema: type | str,
    prepare: Callable[[list[str]], list[str]] | str | None = None,
) -> Callable:
    """Decorate ``fn(cfg: schema, raw: DictConfig)`` into a Hydra main with the shared handling.

    Args:
        config_name: the primary config ``conf/<name>.yaml`` (and help ``hydra/help/<name>``).
        schema: the config dataclass, or its name in :mod:`truckrl.config.schemas` (imported only once
            ``--help`` is ruled out).
        prepare: optional check/rewrite of the command-line arguments before Hydra runs (may
            raise ``ConfigError`` / ``CheckpointError``), or its ``"module:function"`` name.
    """

    def decorate(fn: Callable[[Any, Any], Any]) -> Callable[[], None]:
        @functools.wraps(fn)
        def main() -> None:
            if not TYPED_ARGV:
                TYPED_ARGV[:] = sys.argv
            argv = sys.argv[1:]
            exit_on_help(config_name)
            try:
                with one_line_errors():
                    cls = _schema(schema)
                    _SCHEMA[:] = [cls]
                    if prepare is not None:
                        argv = _function(prepare)(argv)
                    sys.argv[1:] = with_task_presets(argv)
                    _remember_run_dir(sys.argv[1:])
                    _hydra_main(config_name, cls, fn)()
            except KeyboardInterrupt:  # Ctrl-C outside training's own handling (start-up, play)
                print(f"interrupted: {config_name} stopped by Ctrl-C", file=sys.stderr)
                sys.exit(130)

        return main

    return decorate


def _function(f: Callable | str) -> Callable:
    import importlib

    module, _, name = f.partition(":") if isinstance(f, str) else ("", "", "")
    return getattr(importlib.import_module(module), name) if module else f


def _schema(schema: type | str) -> type:
    return _function(f"truckrl.config.schemas:{schema}") if isinstance(schema, str) else schema


def _hydra_main(config_name: str, cls: type, fn: Callable) -> Callable[[], None]:
    import hydra

    from truckrl.config.schemas import register

    register()

    @hydra.main(version_base=None, config_path=CONFIG_PATH, config_name=config_name)
    @functools.wraps(fn)
    def task(raw: Any) -> Any:  # the command's value: a sweeper's objective (+launch=optuna)
        try:
            with one_line_errors(in_task=True):
                return fn(to_config(cls, raw), raw)
        except Exception as e:
            setattr(e, _FROM_TASK, True)
            raise

    return task


@contextlib.contextmanager
def one_line_errors(in_task: bool = False) -> Iterator[None]:
    """Turn user errors into :func:`fail` (one line, exit 2); leave real bugs their traceback.

    Outside the task function this also covers Hydra's composition errors: Hydra reports those
    through ``hydra._internal.utils.run_and_report`` (a multi-line message and exit 1), which is
    wrapped here for the duration of the block.
    """
    from truckrl.config.fields import ConfigError
    from truckrl.rl.checkpoint import CheckpointError

    patched = None if in_task else _wrap_run_and_report()
    try:
        yield
    except (ConfigError, CheckpointError) as e:
        if in_task:
            remove_fresh_output_dir()
        fail(str(e))
    finally:
        if patched is not None:
            patched()


def _remember_run_dir(argv: list[str]) -> None:
    """Note what a named ``hydra.run.dir`` held before Hydra writes into it, and whether the root
    of the default run dirs (``./outputs``) existed."""
    outputs = (Path.cwd() / _OUTPUTS).resolve()
    _KEEP[outputs] = outputs if outputs.exists() else outputs.parent
    _SWEEP_ROOTS[:] = [(outputs / "multirun", _KEEP[outputs])]
    for a in argv:
        if a.lstrip("+").startswith("hydra.sweep.dir="):
            d = Path(a.split("=", 1)[1].strip("'\"")).resolve()
            _SWEEP_ROOTS.append((d, next(p for p in (d, *d.parents) if p.exists())))
        if a.lstrip("+").startswith("hydra.run.dir="):
            d = Path(a.split("=", 1)[1].strip("'\"")).resolve()
            if d.is_dir():
                _BEFORE[d] = {p.name for p in d.iterdir()}
            else:
                _KEEP[d] = next(p for p in d.parents if p.exists())


def remove_fresh_output_dir() -> None:
    """Undo what Hydra wrote for a rejected job (``.hydra/``, an empty job log, the dir itself if
    it made it) when nothing else was written: a rejected run leaves no stray dir."""
    from hydra.core.hydra_config import HydraConfig

    try:
        hc = HydraConfig.get()
        out = Path(hc.runtime.output_dir).resolve()
    except ValueError:  # not under Hydra
        return
    if out == Path.cwd().resolve() or not out.is_dir():
        return
    before = _BEFORE.get(out)
    made = {p.name for p in out.iterdir()} - (before or set())
    log = out / f"{hc.job.name}.log"
    ours = {str(hc.output_subdir), log.name}
    if any(n not in ours and not _empty_dir(out / n) for n in made):
        return  # the job wrote something of its own: keep it
    for name in made:
        target = out / name
        shutil.rmtree(target) if target.is_dir() else target.unlink()
    if before is None:  # Hydra made it, and the folders above it up to what existed
        outputs = (Path.cwd() / _OUTPUTS).resolve()
        default = _KEEP.get(outputs, outputs) if outputs in out.parents else out.parent.parent
        keep = _KEEP.get(out, default)
        with contextlib.suppress(OSError):
            for d in (out, *out.parents):
                if d == keep:
                    break
                d.rmdir()


def _remove_fresh_sweep_dirs() -> None:
    """Delete sweep dirs this process made that hold only Hydra's ``multirun.yaml`` (a sweep whose
    overrides were rejected), and the folders above them it made."""
    for root, keep in _SWEEP_ROOTS:
        for marker in list(root.rglob("multirun.yaml")) if root.is_dir() else []:
            d = marker.parent
            fresh = marker.stat().st_mtime >= _STARTED - 1
            if not fresh or [p.name for p in d.iterdir()] != [marker.name]:
                continue
            marker.unlink()
            with contextlib.suppress(OSError):
                for p in (d, *d.parents):
                    if p == keep:
                        break
                    p.rmdir()


def _empty_dir(p: Path) -> bool:
    return p.is_dir() and not any(p.iterdir())


def _wrap_run_and_report() -> Callable[[], None] | None:
    """Wrap Hydra's error reporter; return the function that restores it."""
    try:
        from hydra._internal import utils as hydra_utils
    except ImportError:  # pragma: no cover - another Hydra layout: keep its own reporting
        return None
    original = hydra_utils.run_and_report

    def run_and_report(func: Callable[[], Any]) -> Any:
        try:
            return func()
        except Exception as e:
            message = None if getattr(e, _FROM_TASK, False) else describe_hydra_error(e)
            if message is None:
                return original(lambda err=e: _reraise(err))
            with contextlib.suppress(OSError):
                _remove_fresh_sweep_dirs()
            fail(message)

    hydra_utils.run_and_report = run_and_report
    return lambda: setattr(hydra_utils, "run_and_report", original)


def _reraise(e: BaseException) -> NoReturn:
    raise e


def describe_hydra_error(e: BaseException) -> str | None:
    """One line for an error Hydra or OmegaConf raised while composing (None: not a user error).

    Names the full dotted field and what it accepts (type, range, unit, from the field's spec).
    """
    from hydra.errors import (
        ConfigCompositionException,
        MissingConfigException,
        OverrideParseException,
    )
    from omegaconf.errors import OmegaConfBaseException

    if isinstance(e, MissingConfigException):
        missing = str(getattr(e, "missing_cfg_file", "") or "")
        group, _, option = missing.rpartition("/")
        options = list(getattr(e, "options", None) or [])
        if group and options:
            return f"{group}={option}: no such option; {group} is one of: {', '.join(options)}"
        return str(e).strip().splitlines()[0]
    if isinstance(e, OverrideParseException):
        return (
            f"cannot parse the override {e.override!r}: write key=value, lists as [a,b], and "
            "quote values with special characters ('a b')"
        )
    cause = e.__cause__ if isinstance(e, ConfigCompositionException) else e
    if isinstance(cause, OmegaConfBaseException) and getattr(cause, "full_key", None):
        return describe_field_error(cause)
    if isinstance(e, ConfigCompositionException | OmegaConfBaseException):
        return str(e).strip().splitlines()[0]
    if isinstance(e, OSError) and e.filename:  # e.g. Hydra making an unwritable run dir
        return f"cannot write {e.filename}: {e.strerror or e}"
    return None


def describe_field_error(e: Any) -> str:
    """One line for an OmegaConf error about field ``e.full_key`` (wrong type, unknown key...)."""
    from omegaconf.errors import ConfigAttributeError, ConfigKeyError

    key = str(e.full_key)
    value = getattr(e, "value", None)
    if isinstance(e, ConfigAttributeError | ConfigKeyError) and value is None:
        parent, _, name = key.rpartition(".")
        known = _known_fields(parent)
        close = difflib.get_close_matches(name, known, n=1)
        hint = f" (did you mean {parent + '.' if parent else ''}{close[0]}?)" if close else ""
        where = parent or "the top level"
        return (
            f"unknown field {key}{hint}; truckrl tools configs {parent} lists the fields of {where}"
        ).replace("configs  lists", "configs lists")
    hint, spec = field_spec(key)
    if hint is not None and dataclasses.is_dataclass(hint):
        first = dataclasses.fields(hint)[0].name
        return (
            f"{key} = {value!r}: {key} is a group of fields, not a value; set a field such as "
            f"{key}.{first}=... (truckrl tools configs {key} lists them)"
        )
    return f"{key} = {value!r} is not allowed: {accepted(hint, spec)}"


def _known_fields(dotted: str) -> list[str]:
    cls = field_spec(dotted)[0] if dotted else _root()
    return [f.name for f in dataclasses.fields(cls)] if dataclasses.is_dataclass(cls) else []


def _root() -> type:
    if _SCHEMA:
        return _SCHEMA[0]
    from truckrl.config.schemas import TrainConfig

    return TrainConfig


def field_spec(dotted: str, root: type | None = None) -> tuple[Any, Any]:
    """``(type hint, Spec)`` of a dotted field (``env.lidar.num_beams``; list indices dropped),
    searched from ``root`` (default: the running entry's schema) and every task's config under
    ``env.task``. ``(None, None)`` when unknown."""
    import re

    from truckrl.tasks import TaskConfig, task_class, task_names

    parts = re.sub(r"\[\d+\]", "", dotted).split(".")
    candidates: list[type] = [root or _root()]
    for i, part in enumerate(parts):
        # every candidate class with this field: tasks share names (env.task.scene) but not
        # their fields, so the search follows all of them
        found = []
        for cls in candidates:
            if not dataclasses.is_dataclass(cls):
                continue
            hints = typing.get_type_hints(cls)
            found += [
                (hints[f.name], f.metadata.get("spec"))
                for f in dataclasses.fields(cls)
                if f.name == part
            ]
        if not found:
            return None, None
        if i == len(parts) - 1:
            return found[0]
        candidates = []
        for hint, _ in found:
            if hint is Any or isinstance(hint, type) and issubclass(hint, TaskConfig):  # env.task
                candidates += [task_class(n).config_class for n in task_names()]
            else:
                candidates.append(hint)
    return None, None


def accepted(hint: Any, spec: Any) -> str:
    """What a field accepts, in words: ``a whole number in [1, 4096] (LiDAR beams R)``."""
    args = typing.get_args(hint)
    nullable = type(None) in args
    if nullable:
        hint = next(a for a in args if a is not type(None))
    rng = f" in {spec.range_text()}" if spec is not None and spec.choices is None else ""
    if hint is bool:
        text = "true or false"
    elif hint is int:
        text = f"a whole number{rng}"
    elif hint is float:
        text = f"a number{rng}"
    elif hint is str and spec is not None and spec.choices:
        text = "one of " + " | ".join(spec.choices)
    elif hint is str:
        text = "a string"
    elif typing.get_origin(hint) is tuple:
        inner = typing.get_args(hint)
        kind = "whole numbers" if inner and inner[0] is int else "numbers"
        if len(inner) == 2 and inner[1] is not Ellipsis:
            text = f"a [min, max] pair of {kind}{rng}"
        else:
            text = f"a list of {kind}{rng} such as [1,2]"
    else:
        text = f"a value of type {getattr(hint, '__name__', hint)}"
    if nullable:
        text += ", or null"
    if spec is not None and spec.unit and spec.unit != "-":
        text += f" [{spec.unit}]"
    if spec is not None and spec.doc:
        text += f" ({spec.doc})"
    return text


def seed_everything(seed: int) -> None:
    """Seed torch, numpy's global generator (third-party code draws from it) and ``random``."""
    import random

    import numpy as np
    import torch

    torch.manual_seed(seed)
    np.random.seed(seed % 2**32)  # noqa: NPY002
    random.seed(seed)


def git_revision() -> dict[str, str | bool]:
    """The source's git commit and whether the work tree had changes (``{}`` outside git)."""
    root = Path(__file__).resolve().parent.parent
    if not (root / ".git").exists():  # an installed copy: not this source tree's repository
        return {}

    def git(*args: str) -> str:
        return subprocess.run(
            ["git", *args], cwd=root, capture_output=True, text=True, timeout=10, check=True
        ).stdout.strip()

    try:
        commit = git("rev-parse", "HEAD")
        dirty = bool(git("status", "--porcelain", "--untracked-files=no"))
    except (OSError, subprocess.SubprocessError):
        return {}
    return {"commit": commit, "dirty": dirty}


#: The command line as typed, kept before it is rewritten (``truckrl.__main__`` sets it before
#: ``runpy`` replaces ``argv[0]``; :func:`hydra_entry` before the task presets join it).
TYPED_ARGV: list[str] = []


def invoked_command(argv: list[str] | None = None) -> str:
    """The command line as typed: ``truckrl <command> ...`` for the console script (Hydra
    commands see ``argv[0]`` rewritten to ``truckrl <command>``), else ``python <argv>``."""
    import os
    import shlex

    argv = list((TYPED_ARGV or sys.argv) if argv is None else argv)
    head, rest = (argv[0] if argv else ""), argv[1:]
    if head.startswith("truckrl "):
        return shlex.join([*head.split(" "), *rest])
    if os.path.basename(head) == "truckrl":
        return shlex.join(["truckrl", *rest])
    return shlex.join(["python", *argv])


def provenance(device: str = "cpu") -> dict[str, Any]:
    """Where a figure came from, as the docs' generated pages print it: the command, the
    machine, the source commit (``-dirty`` when the work tree had changes), the UTC date, torch's
    CPU threads, the device and the 1-minute load average (figures from a loaded machine are not
    comparable with an idle one's)."""
    import datetime
    import os
    import platform

    import torch

    rev = git_revision()
    commit = rev.get("commit")
    if commit and rev.get("dirty"):
        commit = f"{commit}-dirty"
    cpu = platform.processor() or platform.machine()
    return {
        "command": invoked_command(),
        "machine": f"{platform.system()} {platform.release()}, {cpu}, {os.cpu_count()} CPUs, "
        f"Python {platform.python_version()}, torch {torch.__version__}",
        "commit": commit or "not recorded (not a git checkout)",
        "date": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
        "threads": torch.get_num_threads(),
        "device": device,
        "load_avg_1min": round(os.getloadavg()[0], 2) if hasattr(os, "getloadavg") else None,
    }


def check_writable(path: Path, field: str) -> None:
    """Create ``path``'s folder and a probe file in it, or raise ``ConfigError`` naming ``field``
    (one line). JSON files are written by replacing ``path`` with a file made in the same folder,
    so a writable folder is what the final write needs."""
    import tempfile

    from truckrl.config.fields import ConfigError

    try:
        if path.is_dir():
            raise IsADirectoryError(21, "is a directory")
        path.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp"):
            pass
    except OSError as e:
        raise ConfigError(f"{field}={path}: cannot write there ({e.strerror or e})") from None
