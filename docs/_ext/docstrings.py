"""How the site reads the package's docstrings: four adjustments to autodoc and napoleon.

1. Napoleon is not applied to the ``#:`` comments of module data and class attributes, nor to
   properties. It reads their first ``text: more`` as ``type: description``, and the package
   writes them as prose (``#: [m] Scale of goal positions ... (paper: "scaled by 50 meters")``).
2. ``|x|`` outside inline literals is an absolute value, as the package writes it; RST would read
   it as a substitution (the package defines none), so the bars are escaped.
3. A module docstring rendered on a narrative page (the task pages show their task's rules from
   ``task.py`` and ``scene.py``) is replaced on the API pages by a link to that page: rendered
   twice, its section titles would be two targets of one name. The map is the config value
   ``docstring_pages`` (``{module: docname}``).
4. A Python cross-reference to a name that a package re-exports (``truckrl.env.TruckEnv``,
   ``truckrl.tasks.EnvConfig``) resolves to where the object is defined and documented
   (``truckrl.env.truck_env.TruckEnv``), found by importing it. One that names an object
   relative to the module it is written in (``:func:`episode_bins``` in a module that imports
   it, ``:exc:`ConfigError```) resolves to the documented object whose dotted name ends with
   it; of several, to the one that shares the longest package prefix with the referring module
   (``INFO_KEYS`` in ``truckrl.tasks.uturn.task`` is ``truckrl.tasks.uturn.scene.INFO_KEYS``).
   A member that a class inherits (``DockTask.reverse``) resolves to the base class that
   documents it (``Task.reverse``). A name that the referring module imports from outside
   truckrl (``Path`` in a signature) is shown as plain text: there is no offline inventory of
   other projects to link to. A tie stays a warning and none stays a missing reference: the
   nitpicky build fails on both.
"""

from __future__ import annotations

import importlib
import re
from typing import Any

from docutils import nodes
from sphinx.application import Sphinx
from sphinx.environment import BuildEnvironment
from sphinx.util.nodes import make_refnode

_NO_NAPOLEON = ("attribute", "data", "property")
_saved: dict[str, list[str]] = {}
# an inline literal (``x`` or `x`, with any role prefix) or an |absolute value| outside one
_LITERAL_OR_BARS = re.compile(r"(``.+?``|`[^`]+`)|\|(?=\S)([^|`\n]*?\S)\|")


def _save(app: Sphinx, what: str, name: str, obj: Any, options: Any, lines: list[str]) -> None:
    """Before napoleon (priority 400 < its 500): keep a data docstring as written."""
    if what in _NO_NAPOLEON:
        _saved[name] = list(lines)


def _bars(line: str) -> str:
    """``line`` with each ``|x|`` outside inline literals escaped (module doc, item 2)."""
    if line.lstrip().startswith(("| ", "+-", "+=")):  # a line block or a grid table
        return line
    return _LITERAL_OR_BARS.sub(lambda m: m.group(1) or rf"\|{m.group(2)}\|", line)


def _restore(app: Sphinx, what: str, name: str, obj: Any, options: Any, lines: list[str]) -> None:
    """After napoleon: put a kept data docstring back, escape absolute values, and replace a
    module docstring that a narrative page shows (module doc, items 1 to 3)."""
    if what in _NO_NAPOLEON and name in _saved:
        lines[:] = _saved.pop(name)
    lines[:] = [_bars(line) for line in lines]
    page = app.config.docstring_pages.get(name) if what == "module" else None
    if page and app.env.docname != page:
        lines[:] = [f"Its rules and their reasons are on the page :doc:`/{page}`.", ""]


def _shared_prefix(a: str, b: str) -> int:
    n = 0
    for x, y in zip(a.split("."), b.split("."), strict=False):
        if x != y:
            break
        n += 1
    return n


def _defined_at(target: str) -> str | None:
    """``module.qualname`` where the object named ``target`` (``pkg.mod.Name``) is defined, by
    importing the longest importable prefix of ``target``; None when it is not found."""
    parts = target.split(".")
    for i in range(len(parts) - 1, 0, -1):
        try:
            obj: Any = importlib.import_module(".".join(parts[:i]))
        except ImportError:
            continue
        for attr in parts[i:]:
            obj = getattr(obj, attr, None)
        module, qualname = getattr(obj, "__module__", None), getattr(obj, "__qualname__", None)
        return f"{module}.{qualname}" if module and qualname else None
    return None


def _inherited(domain: Any, module: str, target: str) -> str | None:
    """The documented ``Base.member`` that ``Class.member`` (``target``, relative to
    ``module`` or absolute) inherits, by the class's method resolution order."""
    owner_name, _, member = target.rpartition(".")
    if not owner_name:
        return None
    for name in (f"{module}.{owner_name}", owner_name):
        defined = _defined_at(name) if name.startswith("truckrl.") else None
        if defined is None:
            continue
        module_name, _, qualname = defined.rpartition(".")
        owner: Any = importlib.import_module(module_name)
        for part in qualname.split("."):
            owner = getattr(owner, part, None)
        for base in getattr(owner, "__mro__", ())[1:]:
            candidate = f"{base.__module__}.{base.__qualname__}.{member}"
            if candidate in domain.objects:
                return candidate
    return None


def _external(module: str, target: str) -> bool:
    """Whether ``target``'s first name, looked up in ``module``, is an object from outside
    truckrl (a class, function or module of another package)."""
    try:
        namespace = importlib.import_module(module)
    except (ImportError, ValueError):
        return False
    obj = getattr(namespace, target.split(".")[0], None)
    if obj is None:
        return False
    origin = getattr(obj, "__module__", None) or getattr(obj, "__name__", None)
    return isinstance(origin, str) and origin.split(".")[0] != "truckrl"


def _resolve_relative(
    app: Sphinx, env: BuildEnvironment, node: nodes.Element, contnode: nodes.Element
) -> nodes.Element | None:
    """Resolve a Python reference by the documented object ending in its target (item 4)."""
    if node.get("refdomain") != "py":
        return None
    domain = env.domains["py"]
    module = node.get("py:module") or ""
    target = node["reftarget"]
    if node.get("refspecific"):  # the domain has searched by suffix already (type annotations)
        return contnode if module and _external(module, target) else None
    if target.startswith("truckrl."):
        defined = _defined_at(target)
        if defined and defined != target:
            obj = domain.objects.get(defined)
            if obj is not None:
                return make_refnode(
                    app.builder, node["refdoc"], obj.docname, obj.node_id, contnode, defined
                )
    matches = domain.find_obj(
        env, module, node.get("py:class"), target, node["reftype"], searchmode=1
    )
    if not matches:
        inherited = _inherited(domain, module, target)
        if inherited:
            matches = [(inherited, domain.objects[inherited])]
    if len(matches) > 1:
        best = max(_shared_prefix(module, name) for name, _ in matches)
        matches = [(n, o) for n, o in matches if _shared_prefix(module, n) == best]
    if not matches and module and _external(module, target):
        return contnode
    if len(matches) != 1:
        node["refspecific"] = True  # let the domain report the tie, or fall through as missing
        return domain.resolve_xref(
            env, node["refdoc"], app.builder, node["reftype"], target, node, contnode
        )
    name, obj = matches[0]
    return make_refnode(app.builder, node["refdoc"], obj.docname, obj.node_id, contnode, name)


def setup(app: Sphinx) -> dict:
    app.add_config_value("docstring_pages", {}, "env", dict)
    app.setup_extension("sphinx.ext.autodoc")
    app.connect("autodoc-process-docstring", _save, priority=400)
    app.connect("autodoc-process-docstring", _restore, priority=600)
    app.connect("missing-reference", _resolve_relative)
    return {"version": "1", "parallel_read_safe": True, "parallel_write_safe": True}
