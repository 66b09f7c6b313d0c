"""The README stays true: every command line it shows names a real command whose ``key=value``
arguments are accepted, its ``make`` targets exist, and its Python example runs.

What is read from README.md (whatever it holds when the tests run):

- every line of a fenced ``bash`` / ``sh`` / ``shell`` / ``console`` block (``#`` comments cut,
  ``\\`` continuations joined);
- every inline code span that starts with ``truckrl``, ``python -m truckrl`` or ``make``.

How a line is checked, by its program (nothing is run: no training, no output files):

- ``truckrl <command> ...``: ``truckrl --help`` lists the command (``truckrl tools --help`` the
  tool). ``train``, ``eval``, ``play`` and ``export`` compose their Hydra config with the
  arguments as the command does (its own argument rewriting, then
  :func:`truckrl.cli.compose_config`, which validates the config); with ``-m`` each sweep value
  is composed. ``plan``, ``bench`` and ``tools`` parse their arguments with their own parser and
  stop where the work would start.
- ``python -m truckrl.<module> ...``: the module exists and is checked as the command it runs.
- ``make <target> [VAR=VALUE]``: the Makefile has the target and its recipe uses each variable;
  a recipe line that runs ``truckrl ... $(ARGS)`` is checked as that command line.
- any other program (``tensorboard``): it is installed beside this Python or on ``PATH``.

The synopsis notation of the README's tables, each rule named where it is applied:

- ``ALTERNATIVES``: ``a\\|b\\|c`` (a table cell's escaped ``|``) checks each of a, b, c.
- ``OPTIONAL``: ``[key=VALUE ...]`` after a space is an optional group: checked once without it
  and once with it when every word is a concrete ``key=value``; dropped when generic
  (``[overrides]``, ``[key=value ...]``, ``[train.KEY=VALUE ...]``, ``[PREFIX]``).
- ``ELLIPSIS``: ``...`` stands for more arguments and is dropped.
- ``TEMPLATE``: ``<command>`` and ``<tool>`` check every command or tool ``--help`` lists.
- ``PLACEHOLDERS``: upper-case stand-ins in values (``RUN_DIR``, ``CKPT``, ``outputs/DATE/TIME``,
  ``PLAN.json``...) become real values: a run dir with a checkpoint, a file name, a task. A
  stand-in not in that table fails the test until it is added there.

``TRUCKRL_README=<path>`` checks another file instead of README.md (e.g. a copy with a planted
bad override, to see these tests fail).
"""

from __future__ import annotations

import contextlib
import dataclasses
import importlib
import importlib.util
import inspect
import io
import itertools
import os
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any
from unittest import mock

import pytest

from tests.conftest import ROOT
from truckrl.__main__ import HYDRA, PLAIN, TOOLS

README = Path(os.environ.get("TRUCKRL_README") or ROOT / "README.md")
MAKEFILE = ROOT / "Makefile"

#: Fenced blocks whose lines are shell commands.
SHELL_LANGS = ("bash", "sh", "shell", "console")
#: An inline code span that is a command line.
COMMAND_SPAN = re.compile(r"^(truckrl|python3? -m truckrl[\w.]*|make)(\s|$)")
#: Shell words that are no program to look for.
SHELL_BUILTINS = {".", "source", "cd", "export", "set", "echo"}
#: Hydra's own flags: those that take a value, and those that do not (``-m``: a sweep).
HYDRA_FLAGS_WITH_VALUE = {"--cfg", "-c", "--package", "-p", "--info", "-i", "--config-name", "-cn"}
HYDRA_FLAGS = {"--resolve", "--run", "-r", "--multirun", "-m"}


class ReadmeError(AssertionError):
    """A README command line that does not hold."""


# ------------------------------------------------------------------------------ reading the text
@dataclasses.dataclass(frozen=True)
class Line:
    """One command line of the README: ``text`` as written, ``where`` ``README.md:<line>``."""

    text: str
    where: str


def fenced_blocks(text: str) -> list[tuple[str, str, int]]:
    """``(language, body, first line number of the body)`` of every fenced code block."""
    blocks, lang, body, start = [], None, [], 0
    fence = ""
    for number, raw in enumerate(text.splitlines(), 1):
        stripped = raw.strip()
        if lang is None:
            opened = re.match(r"^(```+|~~~+)\s*([\w+-]*)", stripped)
            if opened:
                fence, lang, body, start = opened.group(1), opened.group(2).lower(), [], number + 1
        elif stripped.startswith(fence) and stripped.strip(fence[0]) == "":
            blocks.append((lang, "\n".join(body), start))
            lang = None
        else:
            body.append(raw)
    return blocks


def command_lines(text: str, name: str = "README.md") -> list[Line]:
    """Every command line of a Markdown text (see the module docstring)."""
    found: list[Line] = []
    for lang, body, start in fenced_blocks(text):
        if lang not in SHELL_LANGS:
            continue
        joined, first = "", start
        for offset, raw in enumerate(body.splitlines()):
            line = raw.strip()
            if lang == "console":
                line = line.removeprefix("$ ") if line.startswith("$ ") else ""
            if not joined:
                first = start + offset
            joined = f"{joined} {line}".strip()
            if joined.endswith("\\"):  # a continuation
                joined = joined[:-1]
                continue
            words = shlex.split(joined, comments=True) if joined else []
            if words:
                found.append(Line(shlex.join(words), f"{name}:{first}"))
            joined = ""
    # inline spans outside the fenced blocks (blanked, so that line numbers hold)
    prose = re.sub(
        r"^(```+|~~~+).*?^\1[ \t]*$",
        lambda m: "\n" * m.group(0).count("\n"),
        text,
        flags=re.M | re.S,
    )
    for m in re.finditer(r"(?<!`)`([^`]+)`(?!`)", prose):
        span = " ".join(m.group(1).split())
        if COMMAND_SPAN.match(span):
            found.append(Line(span, f"{name}:{prose.count(chr(10), 0, m.start()) + 1}"))
    return found


def python_example(text: str) -> str | None:
    """The README's first fenced ``python`` block, or None."""
    return next((body for lang, body, _ in fenced_blocks(text) if lang in ("python", "py")), None)


# ---------------------------------------------------------------------------- synopsis notation
def placeholders(run_dir: Path) -> dict[str, str]:
    """PLACEHOLDERS: upper-case stand-ins of the README -> real values, longest first."""
    from truckrl.tasks.config import DEFAULT_TASK

    run = str(run_dir)
    table = {
        "outputs/DATE/TIME": run,  # a run dir as Hydra names it by default
        "RUN_DIR": run,
        "CKPT": run,
        "PLAN.json": "plan.json",
        "FILE": "file",
        "NAME": DEFAULT_TASK,
        "A": run,  # checkpoints=[A,B]
        "B": run,
    }
    return dict(sorted(table.items(), key=lambda kv: -len(kv[0])))


def is_generic(word: str) -> bool:
    """A synopsis word that stands for arguments rather than being one (``key=value``,
    ``train.KEY=VALUE``, ``overrides``, ``PREFIX``, ``...``)."""
    key, sep, _ = word.partition("=")
    if word in ("...", "…"):
        return True
    if not sep:
        return True  # OPTIONAL: a bare word in brackets is a named stand-in ([PREFIX], [overrides])
    return bool(re.search(r"(^|\.)(key|KEY|FIELD|[A-Z_]+)$", key))


def expand(line: Line, commands: dict[str, list[str]], table: dict[str, str]) -> list[list[str]]:
    """The argument lists a synopsis line stands for (rules in the module docstring)."""
    text = line.text
    # TEMPLATE: <command>, <tool>
    templates = re.findall(r"<(\w+)>", text)
    for name in templates:
        if name not in commands:
            raise ReadmeError(f"{line.where}: {text!r}: unknown template <{name}>")
    if templates:
        out = []
        for values in itertools.product(*(commands[n] for n in templates)):
            filled = text
            for name, value in zip(templates, values, strict=True):
                filled = filled.replace(f"<{name}>", value, 1)
            out += expand(Line(filled, line.where), commands, table)
        return out
    # ALTERNATIVES: a\|b\|c in a table cell
    if "\\|" in text:
        word = next(w for w in text.split() if "\\|" in w)
        out = []
        for alternative in word.split("\\|"):
            out += expand(Line(text.replace(word, alternative, 1), line.where), commands, table)
        return out
    try:
        words = shlex.split(text)
    except ValueError as e:
        raise ReadmeError(f"{line.where}: {text!r}: not a shell line ({e})") from None
    base, optional = [], []
    group: list[str] | None = None
    for word in words:
        if group is None and word.startswith("["):
            group = []  # OPTIONAL: a group opens (a list value such as [A,B] follows its key=)
            word = word[1:]
        if group is not None:
            closes = word.endswith("]")
            word = word[:-1] if closes else word
            if word:
                group.append(word)
            if closes:
                if not any(is_generic(w) for w in group):
                    optional += group
                group = None
            continue
        if word not in ("...", "…"):  # ELLIPSIS
            base.append(word)
    if group is not None:
        raise ReadmeError(f"{line.where}: {text!r}: an optional group [ ... ] is not closed")
    variants = [base] + ([base + optional] if optional else [])
    return [[fill(w, table, line) for w in v] for v in variants]


def fill(word: str, table: dict[str, str], line: Line) -> str:
    """PLACEHOLDERS: ``word`` with its stand-ins replaced; an unknown one fails."""
    key, sep, value = word.partition("=")
    if not sep or word.startswith("-"):
        return word
    patterns = {
        rf"(?<![\w/.]){re.escape(stand_in)}(?!\w)": real for stand_in, real in table.items()
    }
    bare = value
    for pattern in patterns:
        bare = re.sub(pattern, "", bare)
    left = re.findall(r"\b[A-Z][A-Z0-9_]*\b", bare)  # before the real values: a path may hold any
    if left:
        raise ReadmeError(
            f"{line.where}: {line.text!r}: the stand-in {left[0]} has no real value: add it to "
            "tests/test_readme.py placeholders()"
        )
    for pattern, real in patterns.items():
        value = re.sub(pattern, real.replace("\\", "\\\\"), value)
    return f"{key}={value}"


# ------------------------------------------------------------------------------------ checking
def _listed(text: str, heading: str) -> list[str]:
    """The names of a help text's ``heading:`` section (two-space indented rows)."""
    rows = text.split(f"\n{heading}:\n", 1)[1].split("\n\n", 1)[0]
    return [row.split()[0] for row in rows.splitlines() if row.startswith("  ")]


def listed_commands() -> dict[str, list[str]]:
    """What ``truckrl --help`` and ``truckrl tools --help`` list: ``{"command": [...],
    "tool": [...]}``."""
    from truckrl.__main__ import main

    out = {}
    for args, heading, key in (
        (["--help"], "commands", "command"),
        (["tools", "--help"], "tools", "tool"),
    ):
        buffer = io.StringIO()
        with contextlib.redirect_stdout(buffer):
            assert main(args) == 0
        out[key] = _listed(buffer.getvalue(), heading)
    return out


def hydra_entry_of(command: str) -> dict[str, Any]:
    """The ``config_name``, ``schema`` and ``prepare`` that :func:`truckrl.cli.hydra_entry` gave the
    command's ``main``."""
    from truckrl.cli import _function, _schema

    found = inspect.getclosurevars(importlib.import_module(HYDRA[command][0]).main).nonlocals
    if not {"config_name", "schema", "prepare"} <= set(found):
        raise RuntimeError("truckrl.cli.hydra_entry changed: update tests/test_readme.py")
    prepare = found["prepare"]
    return {
        "config_name": found["config_name"],
        "schema": _schema(found["schema"]),
        "prepare": (lambda argv: argv) if prepare is None else _function(prepare),
    }


def sweep_variants(overrides: list[str]) -> list[list[str]]:
    """``-m`` overrides as plain override lists: each sweep value once, the others at their
    first value."""
    from hydra.core.override_parser.overrides_parser import OverridesParser

    parsed = OverridesParser.create().parse_overrides(overrides)
    values = [
        [f"{o.get_key_element()}={v}" for v in o.sweep_string_iterator()]
        if o.is_sweep_override()
        else [o.input_line]
        for o in parsed
    ]
    sweeps = [i for i, choices in enumerate(values) if len(choices) > 1]
    if not sweeps:
        return [[choices[0] for choices in values]]
    return [
        [choice if j == i else choices[0] for j, choices in enumerate(values)]
        for i in sweeps
        for choice in values[i]
    ]


def check_hydra(command: str, args: list[str], where: str) -> None:
    """Compose the command's config with ``args`` as ``truckrl <command>`` would, without a job."""
    from truckrl.cli import compose_config, help_text
    from truckrl.config.fields import ConfigError
    from truckrl.rl.checkpoint import CheckpointError

    entry = hydra_entry_of(command)
    if {"-h", "--help"} & set(args):
        if not help_text(entry["config_name"]).strip():
            raise ReadmeError(f"{where}: truckrl {command} --help prints nothing")
        return
    overrides, sweep, i = [], False, 0
    while i < len(args):
        a = args[i]
        if a in HYDRA_FLAGS_WITH_VALUE:
            i += 2
            continue
        if a.startswith("-"):
            if a not in HYDRA_FLAGS:
                raise ReadmeError(f"{where}: truckrl {command}: {a} is no Hydra flag")
            sweep = sweep or a in ("-m", "--multirun")
        else:
            overrides.append(a)
        i += 1
    try:
        prepared = entry["prepare"](overrides)
        for variant in sweep_variants(prepared) if sweep else [prepared]:
            compose_config(entry["config_name"], entry["schema"], variant)
    except (ConfigError, CheckpointError) as e:
        raise ReadmeError(f"{where}: truckrl {command} {shlex.join(args)}: {e}") from None


def check_plain(argv: list[str], where: str) -> None:
    """Run ``truckrl plan|bench|tools ...`` in this process up to where its work would start:
    the argument parsing runs, the work (``run_or_fail``, a benchmark's ``run``) is stubbed."""
    import truckrl.cli
    from truckrl.__main__ import main
    from truckrl.bench.__main__ import _available

    reached = []

    def stub(*args: Any) -> int:
        reached.append(args)
        return 0

    out, err = io.StringIO(), io.StringIO()
    with contextlib.ExitStack() as stack:
        stack.enter_context(mock.patch.object(truckrl.cli, "run_or_fail", stub))
        for module in _available().values():
            stack.enter_context(mock.patch.object(module, "run", stub))
        stack.enter_context(contextlib.redirect_stdout(out))
        stack.enter_context(contextlib.redirect_stderr(err))
        try:
            code = main(argv)
        except SystemExit as e:
            code = e.code
    if code not in (0, None) or "error:" in err.getvalue():
        said = (err.getvalue() or out.getvalue()).strip()
        raise ReadmeError(f"{where}: truckrl {shlex.join(argv)}: exit {code}: {said}")


def check_truckrl(argv: list[str], where: str, listed: dict[str, list[str]]) -> None:
    """``truckrl argv...``: the command exists and accepts its arguments."""
    if not argv or argv[0] in ("-h", "--help"):
        return
    command, rest = argv[0], argv[1:]
    if command not in listed["command"]:
        raise ReadmeError(f"{where}: truckrl {command}: truckrl --help lists no such command")
    if command == "tools" and rest and not rest[0].startswith("-"):
        if rest[0] not in listed["tool"]:
            raise ReadmeError(
                f"{where}: truckrl tools {rest[0]}: truckrl tools --help lists no such tool"
            )
    if command in HYDRA:
        check_hydra(command, rest, where)
    else:
        check_plain(argv, where)


def module_command(module: str) -> list[str] | None:
    """The ``truckrl`` words that run the same as ``python -m <module>``, or None."""
    if module == "truckrl":
        return []
    for command, (name, _) in (HYDRA | PLAIN).items():
        if module in (name, name.removesuffix(".__main__")):
            return [command]
    for tool, (name, _) in TOOLS.items():
        if module == name:
            return ["tools", tool]
    return None


def make_rules(text: str) -> dict[str, list[str]]:
    """Makefile target -> its recipe lines."""
    rules: dict[str, list[str]] = {}
    current: list[str] = []
    for line in text.splitlines():
        if line.startswith("\t"):
            current.append(line.strip())
            continue
        m = re.match(r"^([^\s:=#][^:=#]*?)\s*:(?![:=])", line)
        current = []
        if m:
            for target in m.group(1).split():
                current = rules.setdefault(target, current)
    return rules


def check_make(words: list[str], where: str, listed: dict[str, list[str]]) -> None:
    """``make target... VAR=VALUE...``: the targets exist, their recipes use the variables, and a
    recipe's ``truckrl ... $(VAR)`` line is checked with the value."""
    rules = make_rules(MAKEFILE.read_text())
    variables = dict(w.split("=", 1) for w in words if "=" in w)
    targets = [w for w in words if "=" not in w and not w.startswith("-")] or [next(iter(rules))]
    for target in targets:
        if target not in rules:
            raise ReadmeError(f"{where}: make {target}: the Makefile has no such target")
        recipe = rules[target]
        for var in variables:
            if not any(f"$({var})" in r for r in recipe):
                raise ReadmeError(f"{where}: make {target} does not use {var}")
        for r in recipe:
            m = re.search(r"(?:^|/)truckrl\s+(.*)$", r)
            if m:
                args = m.group(1).replace("$(ARGS)", variables.get("ARGS", ""))
                check_truckrl(shlex.split(args), where, listed)


def check_line(argv: list[str], where: str, listed: dict[str, list[str]]) -> None:
    """One expanded command line, by its program."""
    program, rest = argv[0], argv[1:]
    if program == "truckrl":
        check_truckrl(rest, where, listed)
    elif program in ("python", "python3") and rest[:1] == ["-m"] and len(rest) > 1:
        module = rest[1]
        if importlib.util.find_spec(module) is None:
            raise ReadmeError(f"{where}: python -m {module}: no such module")
        words = module_command(module)
        if words is None:
            raise ReadmeError(f"{where}: python -m {module}: runs no truckrl command")
        check_truckrl([*words, *rest[2:]], where, listed)
    elif program == "make":
        check_make(rest, where, listed)
    elif program not in SHELL_BUILTINS:
        here = Path(sys.executable).parent / program
        if not (here.exists() or shutil.which(program)):
            raise ReadmeError(
                f"{where}: {program}: not installed (neither in the venv nor on PATH)"
            )


def check_text(text: str, run_dir: Path, name: str = "README.md") -> int:
    """Check every command line of ``text``; the number of argument lists checked."""
    listed = listed_commands()
    commands = {"command": listed["command"], "tool": listed["tool"]}
    table = placeholders(run_dir)
    checked = 0
    for line in command_lines(text, name):
        for argv in expand(line, commands, table):
            check_line(argv, line.where, listed)
            checked += 1
    return checked


# --------------------------------------------------------------------------------------- tests
def _readme_text() -> str:
    if not README.is_file():
        pytest.fail(f"{README} is missing")
    return README.read_text()


LINES = command_lines(README.read_text()) if README.is_file() else []


def test_the_readme_shows_command_lines():
    assert LINES, f"no command line found in {README}: the parser or the README changed"


@pytest.mark.parametrize("line", LINES, ids=lambda line: f"{line.where} {line.text}")
def test_readme_command_line_holds(line, tiny_checkpoint):
    listed = listed_commands()
    table = placeholders(tiny_checkpoint[0])
    for argv in expand(line, {"command": listed["command"], "tool": listed["tool"]}, table):
        check_line(argv, line.where, listed)


def test_readme_python_example_runs(tmp_path):
    """The first fenced ``python`` block, in a fresh interpreter, from a folder outside the
    repository (what a user of the installed package runs)."""
    code = python_example(_readme_text())
    assert code is not None, (
        f"{README} has no ```python block: the README's Python example is missing"
    )
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME")}
    proc = subprocess.run(
        [sys.executable, "-c", code],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, f"the README's Python example failed:\n{proc.stderr[-3000:]}"


# ------------------------------------------------------------------- the checker on planted lines
GOOD = """
```bash
truckrl train experiment=fast ppo.lr=3e-4   # a comment
truckrl train -m ppo.lr=1e-4,3e-4 seed=0,1
make train ARGS="max_minutes=30"
```
Also `truckrl tools configs env.vehicle`, `truckrl bench env\\|lidar [key=value ...]` and
`python -m truckrl.evaluate checkpoint=RUN_DIR [env.max_steps=40]`.
"""


def test_the_checker_passes_good_lines(tiny_checkpoint):
    assert check_text(GOOD, tiny_checkpoint[0]) == 8


@pytest.mark.parametrize(
    ("line", "says"),
    [
        ("truckrl train ppo.lrr=1e-4", "unknown field ppo.lrr"),
        ("truckrl train -m ppo.lr=1e-4,-3", "ppo.lr = -3"),
        ("truckrl train experiment=nope", "experiment=nope: no such option"),
        ("truckrl eval checkpoint=RUN_DIR episodes=0", "episodes = 0"),
        ("truckrl export format=gif", "format"),
        ("truckrl plan episodes=0", "episodes"),
        ("truckrl tools scenes count=4 nope=1", "nope"),
        ("truckrl bench env\\|lidar nope=1", "nope"),
        ("truckrl tools nope", "lists no such tool"),
        ("truckrl nope", "lists no such command"),
        ("python -m truckrl.nope", "no such module"),
        ("make nope", "no such target"),
        ('make lint ARGS="x=1"', "does not use ARGS"),
        ('make train ARGS="ppo.lrr=1"', "unknown field ppo.lrr"),
        ("truckrl eval checkpoint=SOMEWHERE", "the stand-in SOMEWHERE has no real value"),
        ("```bash\nnope-not-a-program --help\n```", "not installed"),
    ],
)
def test_the_checker_catches_a_bad_line(line, says, tiny_checkpoint):
    text = line if line.startswith("```") else f"Run `{line}` here."
    with pytest.raises(ReadmeError, match=re.escape(says)):
        check_text(text, tiny_checkpoint[0])


def test_the_parser_reads_blocks_spans_and_notation():
    text = "```sh\nmake train \\\n  ARGS=1  # c\n```\n\nsee `truckrl play [checkpoint=RUN_DIR]`\n"
    lines = command_lines(text)
    assert lines == [
        Line("make train ARGS=1", "README.md:2"),
        Line("truckrl play [checkpoint=RUN_DIR]", "README.md:6"),
    ]
    assert expand(lines[1], {}, {"RUN_DIR": "r"}) == [
        ["truckrl", "play"],
        ["truckrl", "play", "checkpoint=r"],
    ]
    generic = Line("truckrl tools imitate plan=PLAN.json [train.KEY=VALUE ...]", "x")
    assert expand(generic, {}, {"PLAN.json": "p.json"}) == [
        ["truckrl", "tools", "imitate", "plan=p.json"]
    ]
    assert python_example("```python\nprint(1)\n```\n```python\nprint(2)\n```") == "print(1)"
