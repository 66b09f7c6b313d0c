"""Every module of the package has a layer, and imports go downward only.

Read from the source's import statements (module level and inside functions alike). The layers,
lowest first (``docs/architecture.md``):

=============  ===============================================================================
config         ``truckrl.config`` (``param``, ``build``, ``ConfigError``): pure Python
sim            world physics and geometry any task uses: pure torch
task           the task interface (``truckrl.tasks``) and each task folder's core: its config,
               scene generator, rules, reward, observation extras, evaluation bins
viz            drawing from state snapshots (beside ``env``: it reads states, never steps them)
env            env adapters over the task core (TorchRL's ``EnvBase``)
evaluation     rollouts, held-out checks, tables; a task folder's ``diagnosis``
gym            the Gymnasium and Stable-Baselines3 adapters over ``env`` (and ``viz`` to render)
planning       the planner's search; a task folder's ``expert``
rl             network, PPO, curriculum, collection, checkpoints, imitation, the trainer
viewer         the interactive frame loop
schemas        the entry points' config schemas and their Hydra registration
cli            what the commands share: Hydra entry, one-line errors, ``KEY=VALUE`` parsing
entry          the commands: train, evaluate, play, export, plan, bench, tools (none imports
               another)
main           ``truckrl/__main__.py``, the ``truckrl`` command that dispatches to them
=============  ===============================================================================

A task folder (``truckrl/tasks/<name>/``) spans layers by role: ``expert.py`` and anything under
``expert/`` sit in ``planning``, ``diagnosis.py`` in ``evaluation``, ``tools.py`` and anything
under ``tools/`` (the folder's own commands, ``python -m truckrl.tasks.<name>.tools[.<command>]``)
in ``entry``, the rest in ``task``.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PKG = Path(__file__).resolve().parent.parent / "truckrl"

#: What each layer may import from truckrl (besides itself).
ALLOWED: dict[str, set[str]] = {
    "config": set(),
    "sim": {"config"},
    "task": {"config", "sim"},
    "viz": {"config", "sim", "task"},
    "env": {"config", "sim", "task"},
    "evaluation": {"config", "sim", "task", "env"},
    "gym": {"config", "sim", "task", "viz", "env", "evaluation"},
    "planning": {"config", "sim", "task", "env", "evaluation"},
    "rl": {"config", "sim", "task", "viz", "env", "evaluation", "planning"},
    "viewer": {"config", "sim", "task", "viz", "env", "evaluation", "rl"},
    "schemas": {"config", "sim", "task", "viz", "env", "evaluation", "planning", "rl"},
}
ALLOWED["cli"] = set(ALLOWED) | {"viewer", "schemas"}
ALLOWED["entry"] = ALLOWED["cli"] | {"cli"}
ALLOWED["main"] = ALLOWED["entry"] | {"entry"}
ALLOWED["api"] = ALLOWED["rl"] | {"rl"}

#: Top-level modules and packages of the entry layer: the commands of ``truckrl``.
ENTRY = {"train", "evaluate", "play", "export", "plan", "bench", "tools"}
#: Task-folder modules (by their first name inside the folder) that sit above the task layer.
TASK_ROLES = {"expert": "planning", "diagnosis": "evaluation", "tools": "entry"}


def module_name(path: Path) -> str:
    parts = list(path.relative_to(PKG.parent).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def layer_of(module: str) -> str:
    """The layer of a dotted ``truckrl`` module (see the module docstring)."""
    parts = module.split(".")[1:]
    if not parts:
        return "api"  # the package itself: __version__ and the public names it loads on use
    head = parts[0]
    if head == "config":
        return "schemas" if parts[1:2] == ["schemas"] else "config"
    if head == "tasks":
        role = parts[2] if len(parts) > 2 else None
        return TASK_ROLES.get(role, "task")
    if head in ENTRY:
        return "entry"
    if head == "cli":
        return "cli"
    if head == "__main__":
        return "main"
    if head in ALLOWED:
        return head
    raise KeyError(f"{module} has no layer")


def truckrl_imports(path: Path) -> set[str]:
    """Dotted truckrl modules that ``path`` imports (``from truckrl.x import y`` -> both ``truckrl.x``
    and, when it is a module, ``truckrl.x.y``; ``from truckrl import cli`` -> ``truckrl.cli``)."""
    tree = ast.parse(path.read_text())
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("truckrl"):
            subs = set()
            for a in node.names:
                sub = PKG.parent / Path(*f"{node.module}.{a.name}".split("."))
                if sub.with_suffix(".py").is_file() or sub.is_dir():
                    subs.add(f"{node.module}.{a.name}")
            names |= subs
            # ``from truckrl import cli`` reaches only the submodule: the package's own names
            # (the public API) load on first use, so the package counts only where a name is
            # taken from it
            if node.module != "truckrl" or len(subs) < len(node.names):
                names.add(node.module)
        elif isinstance(node, ast.Import):
            names |= {a.name for a in node.names if a.name.startswith("truckrl")}
    return names


FILES = sorted(PKG.rglob("*.py"))


def test_every_module_has_a_layer():
    for p in FILES:
        assert layer_of(module_name(p)) in ALLOWED, p


@pytest.mark.parametrize("path", FILES, ids=lambda p: str(p.relative_to(PKG)))
def test_imports_go_downward(path):
    layer = layer_of(module_name(path))
    bad = {m for m in truckrl_imports(path) if layer_of(m) not in ALLOWED[layer] | {layer}}
    assert not bad, f"{path.relative_to(PKG)} ({layer}) imports {sorted(bad)}"


@pytest.mark.parametrize("layer", ["config", "sim", "task"])
def test_core_layers_do_not_import_torchrl_or_hydra(layer):
    files = [p for p in FILES if layer_of(module_name(p)) == layer]
    assert len(files) >= 3, files  # the layer's modules are found, so the loop checks some
    for p in files:
        tree = ast.parse(p.read_text())
        for node in ast.walk(tree):
            mods = []
            if isinstance(node, ast.ImportFrom) and node.module:
                mods = [node.module]
            elif isinstance(node, ast.Import):
                mods = [a.name for a in node.names]
            for m in mods:
                assert m.split(".")[0] not in {"torchrl", "hydra", "omegaconf"}, (p, m)


@pytest.mark.parametrize("path", FILES, ids=lambda p: str(p.relative_to(PKG)))
def test_no_command_imports_another(path):
    """A helper two commands share belongs in a lower layer, not in one of them."""
    name = module_name(path)
    if layer_of(name) != "entry":
        return
    head = name.split(".")[1]
    others = {
        m for m in truckrl_imports(path) if layer_of(m) == "entry" and m.split(".")[1] != head
    }
    assert not others, f"{path.relative_to(PKG)} imports the commands {sorted(others)}"


def test_layer_of_knows_the_roles():
    """The map itself, on hand-picked modules (a wrong map would let any import through)."""
    assert layer_of("truckrl.tasks.uturn.task") == "task"
    assert layer_of("truckrl.tasks.uturn.diagnosis") == "evaluation"
    assert layer_of("truckrl.tasks.intersection.expert") == "planning"
    assert layer_of("truckrl.tasks.network.tools.solvable") == "entry"
    assert layer_of("truckrl.config.fields") == "config"
    assert layer_of("truckrl.config.schemas") == "schemas"
    assert layer_of("truckrl.tools.paths") == "entry"
    assert layer_of("truckrl.cli") == "cli" and layer_of("truckrl.__main__") == "main"
    with pytest.raises(KeyError):
        layer_of("truckrl.nowhere")
    assert "viz" not in ALLOWED["env"] and "env" not in ALLOWED["viz"]
    assert layer_of("truckrl.gym.sb3") == "gym" and layer_of("truckrl.gym") == "gym"
    assert "gym" in ALLOWED["entry"] and "gym" not in ALLOWED["rl"] | ALLOWED["api"]
