"""The layers import downward only: sim <- task <- env <- agent <- entry points; viz beside.

Read from the source's import statements (module level and inside functions alike).
"""

import ast
from pathlib import Path

import pytest

PKG = Path(__file__).resolve().parent.parent / "truckrl"

#: What each layer may import from truckrl (besides itself).
ALLOWED = {
    "sim": set(),
    "task": {"sim"},
    "env": {"sim", "task"},
    "agent": {"sim", "task", "env"},
    "viz": {"sim", "task"},  # drawing reads states; sensor placement and body outlines only
}
ENTRY = {
    "train",
    "evaluate",
    "play",
    "imitate",
    "plan",
    "diagnose",
    "paths",
    "export",
    "runner",
    "cli",
    "configs",
    "run_logger",
    "bench",
}


def layer_of(path: Path) -> str:
    rel = path.relative_to(PKG)
    return rel.parts[0] if len(rel.parts) > 1 else rel.stem


def truckrl_imports(path: Path) -> set[str]:
    tree = ast.parse(path.read_text())
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("truckrl."):
            names.add(node.module.split(".")[1])
        elif isinstance(node, ast.Import):
            names |= {a.name.split(".")[1] for a in node.names if a.name.startswith("truckrl.")}
    return names


FILES = sorted(p for p in PKG.rglob("*.py") if layer_of(p) in ALLOWED)


@pytest.mark.parametrize("path", FILES, ids=lambda p: str(p.relative_to(PKG)))
def test_imports_go_downward(path):
    layer = layer_of(path)
    bad = truckrl_imports(path) - ALLOWED[layer] - {layer}
    assert not bad, f"{path.relative_to(PKG)} ({layer}) imports {sorted(bad)}"


def test_every_module_has_a_layer():
    for p in PKG.rglob("*.py"):
        layer = layer_of(p)
        assert layer in ALLOWED or layer in ENTRY or p.name == "__init__.py", p


@pytest.mark.parametrize("layer", ["sim", "task"])
def test_core_layers_do_not_import_torchrl_or_hydra(layer):
    for p in (PKG / layer).rglob("*.py"):
        tree = ast.parse(p.read_text())
        for node in ast.walk(tree):
            mods = []
            if isinstance(node, ast.ImportFrom) and node.module:
                mods = [node.module]
            elif isinstance(node, ast.Import):
                mods = [a.name for a in node.names]
            for m in mods:
                assert m.split(".")[0] not in {"torchrl", "hydra", "omegaconf"}, (p, m)
