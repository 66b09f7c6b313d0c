"""A task is one folder: nothing outside ``truckrl/tasks/<name>/`` names that task or imports from
its folder, and a task folder outside the package (``tests/tasks/reach/``) runs unchanged.

The one name allowed outside a folder is :data:`truckrl.tasks.config.DEFAULT_TASK`, the task a
config without ``task.name`` runs.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

from truckrl.tasks import task_names
from truckrl.tasks.config import DEFAULT_TASK

PKG = Path(__file__).resolve().parent.parent / "truckrl"
HERE = Path(__file__).resolve().parent
TASKS = PKG / "tasks"
#: Where a shipped task's name may appear outside its folder: ``(file, line text)``.
ALLOWED = {(TASKS / "config.py", f'DEFAULT_TASK = "{DEFAULT_TASK}"')}


def _outside(folder: Path) -> list[Path]:
    return [p for p in sorted(PKG.rglob("*")) if p.is_file() and folder not in p.parents]


def _strings_and_imports(path: Path) -> tuple[list[tuple[int, str]], list[tuple[int, str]]]:
    tree = ast.parse(path.read_text())
    strings, imports = [], []
    for node in ast.walk(tree):
        if isinstance(node, ast.Constant) and isinstance(node.value, str):
            strings.append((node.lineno, node.value))
        elif isinstance(node, ast.ImportFrom) and node.module:
            imports += [(node.lineno, f"{node.module}.{a.name}") for a in node.names]
        elif isinstance(node, ast.Import):
            imports += [(node.lineno, a.name) for a in node.names]
    return strings, imports


def test_the_shipped_tasks_are_folders():
    assert task_names() == sorted(p.parent.name for p in TASKS.glob("*/__init__.py"))
    assert DEFAULT_TASK in task_names() and len(task_names()) >= 3


@pytest.mark.parametrize("name", task_names())
def test_no_module_outside_a_task_folder_names_it(name):
    """Python: no string literal that is the name (or a dotted path into the folder), no import
    from the folder. YAML and text files: the name as a word, outside comments."""
    folder = TASKS / name
    word = re.compile(rf"(?<![\w.]){re.escape(name)}(?![\w])")
    found = []
    for path in _outside(folder):
        lines = path.read_text(errors="replace").splitlines() if path.suffix != ".pt" else []
        if path.suffix == ".py":
            strings, imports = _strings_and_imports(path)
            for lineno, text in strings:
                hit = text == name or text.startswith(f"truckrl.tasks.{name}")
                if hit and (path, lines[lineno - 1].strip()) not in ALLOWED:
                    found.append(f"{path.relative_to(PKG)}:{lineno}: {text!r}")
            for lineno, module in imports:
                if module.startswith(f"truckrl.tasks.{name}"):
                    found.append(f"{path.relative_to(PKG)}:{lineno}: imports {module}")
        elif path.suffix in {".yaml", ".yml"}:
            for i, line in enumerate(lines, 1):
                code = line.split("#", 1)[0]
                if word.search(code):
                    found.append(f"{path.relative_to(PKG)}:{i}: {line.strip()}")
    assert not found, f"task {name!r} named outside its folder:\n" + "\n".join(found)


def test_the_test_only_task_is_named_nowhere_in_the_package():
    """The reach folder (tests/tasks/reach/) is a complete task; the package never heard of it:
    no import from ``tests``, no ``"reach"`` literal, none of its class names."""
    names = re.compile(r"\btests\.tasks\b|\bReach(Task|Config)\b")
    hits = []
    for p in sorted(PKG.rglob("*.py")):
        text = p.read_text()
        hits += [f"{p.relative_to(PKG)}: {m.group(0)}" for m in names.finditer(text)]
        strings, imports = _strings_and_imports(p)
        hits += [f"{p.relative_to(PKG)}:{n}" for n, t in strings if t == "reach"]
        hits += [f"{p.relative_to(PKG)}:{n}" for n, m in imports if m.startswith("tests")]
    assert not hits, hits


def test_a_task_folder_outside_the_package_runs_by_its_dotted_name():
    from truckrl.env import TruckEnv
    from truckrl.tasks import task_class

    assert task_class("tests.tasks.reach").__module__ == "tests.tasks.reach.task"
    env = TruckEnv(num_envs=3, seed=0, config={"task": {"name": "tests.tasks.reach"}})
    td = env.rollout(5, break_when_any_done=False)
    env.close()
    assert td["next", "distance_error"].shape == (3, 5, 1)
    assert (HERE / "tasks" / "reach" / "task.py").is_file()
