"""Sphinx directive ``config-reference``: every config field as tables, generated at build time.

The rows are :func:`truckrl.config.fields.spec_table` of the same configs, with the same hidden
rows, as ``truckrl tools configs`` (:func:`truckrl.config.schemas.main`), so the page and the
command cannot disagree; ``tests/test_docs.py`` checks that both list the same field names. The
rows are grouped into one section per config (``env.vehicle``, ``ppo``, ...), each titled by its
dataclass's docstring; the task fields get one section per task, because each task's
``env.task`` config is a different class.

Usage (MyST)::

    ```{config-reference}
    ```

Within a section the field names are shown relative to its prefix (``wheelbase`` in the section
``env.vehicle``), so the tables fit the page. Each section is a ``std`` label ``config-<group>`` with dots as hyphens (``config-env-vehicle``,
``config-env-task-dock``), for ``{ref}`` links from other pages. With an argument, the directive
is one table of the fields whose dotted name starts with it, for a narrative page (no sections,
no labels); ``:task:`` picks the task whose ``env.task`` fields it reads (default: the default
task)::

    ```{config-reference} env.task.reward
    :task: dock
    ```
"""

from __future__ import annotations

import dataclasses
import inspect
import re

from docutils import nodes
from docutils.parsers.rst import directives
from sphinx.application import Sphinx
from sphinx.util.docutils import SphinxDirective

Row = tuple[str, str, str, str, str]  # (dotted name, default, unit, allowed, meaning)

COLUMNS = ("field", "default", "unit", "allowed", "meaning")
WIDTHS = (22, 10, 8, 14, 46)  # relative column widths


def _hidden(name: str) -> bool:
    """The rows ``truckrl tools configs`` leaves out: ``env.task`` itself (its fields are listed
    per task) and ``play.env.*`` (the same env fields, listed once under ``env``)."""
    return name == "env.task" or name.startswith("play.env.")


def _doc_line(cls: type) -> str:
    """First line of ``cls``'s own docstring ('' for a dataclass's generated signature)."""
    doc = inspect.getdoc(cls) or ""
    if not doc or doc.startswith(f"{cls.__name__}("):
        return ""
    return doc.split("\n\n")[0].replace("\n", " ")


def _classes(cls: type, where: str, out: dict[str, type]) -> dict[str, type]:
    """``{dotted prefix: dataclass}`` of ``cls`` and every config nested in it."""
    out[where] = cls
    for f in dataclasses.fields(cls):
        default = f.default_factory() if f.default_factory is not dataclasses.MISSING else f.default
        if dataclasses.is_dataclass(default):
            _classes(type(default), f"{where}.{f.name}" if where else f.name, out)
    return out


def _group(name: str) -> str:
    """Section of a non-task row: run-level fields together, ``env`` split by nested config
    (``env.vehicle``), every other config whole (``ppo``, ``play`` with its view and keys)."""
    parts = name.split(".")
    if len(parts) == 1:
        return ""
    if parts[0] == "env" and len(parts) > 2:
        return ".".join(parts[:2])
    return parts[0]


def reference() -> list[tuple[str, str, list[Row]]]:
    """Sections ``(group, title, rows)`` of every field that ``truckrl tools configs`` prints.

    Group ``""`` holds the run-level fields of ``truckrl train``; ``env.task:<name>`` the fields
    of task ``<name>``.
    """
    from truckrl.config.fields import spec_table
    from truckrl.config.schemas import EvaluateConfig, PlayConfig, TrainConfig
    from truckrl.tasks import task_class, task_names

    classes = _classes(TrainConfig, "", {})
    classes.update(_classes(PlayConfig, "play", {}))
    classes.update(_classes(EvaluateConfig, "evaluate", {}))
    groups: dict[str, list[Row]] = {}
    tables = [spec_table(TrainConfig), spec_table(PlayConfig, "play")]
    tables.append(spec_table(EvaluateConfig, "evaluate"))
    for row in (r for table in tables for r in table):
        if not _hidden(row[0]):
            groups.setdefault(_group(row[0]), []).append(row)
    sections = []
    for group, rows in groups.items():
        if group == "":
            title = "Run: " + _doc_line(TrainConfig)
        else:
            title = f"{group}: {_doc_line(classes[group])}".rstrip(": ")
        sections.append((group, title, rows))
        if group == "env":  # the task sections follow the env's own
            for name in task_names():
                cls = task_class(name).config_class
                rows = [r for r in spec_table(cls, "env.task") if not _hidden(r[0])]
                title = f"env.task for task={name}: {_doc_line(cls)}".rstrip(": ")
                sections.append((f"env.task:{name}", title, rows))
    return sections


def _inline(text: str) -> list[nodes.Node]:
    """``text`` with its backquoted spans as inline literals."""
    out: list[nodes.Node] = []
    for i, part in enumerate(re.split(r"`+", text)):
        if part:
            out.append(nodes.literal(part, part) if i % 2 else nodes.Text(part))
    return out


def _table(rows: list[Row], prefix: str = "") -> nodes.table:
    """The rows as a table; field names are shown without ``prefix`` (the section's)."""
    table = nodes.table(classes=["config-reference"])
    group = nodes.tgroup(cols=len(COLUMNS))
    table += group
    for width in WIDTHS:
        group += nodes.colspec(colwidth=width)
    head = nodes.thead()
    group += head
    body = nodes.tbody()
    group += body
    shown = [(r[0].removeprefix(prefix), *r[1:]) for r in rows]
    for target, cells in [(head, COLUMNS), *((body, r) for r in shown)]:
        line = nodes.row()
        for i, cell in enumerate(cells):
            entry = nodes.entry()
            if target is body and i < 2 and cell:  # field name and default: literal
                entry += nodes.paragraph("", "", nodes.literal(cell, cell))
            else:
                entry += nodes.paragraph("", "", *_inline(cell))
            line += entry
        target += line
    return table


def label(group: str) -> str:
    """The ``std`` label of a section: ``config-`` and the group with dots as hyphens."""
    return "config-" + (re.sub(r"[.:_]", "-", group) if group else "run")


def selected(prefix: str, task: str | None) -> list[Row]:
    """The rows of :func:`reference` whose name starts with ``prefix``, the ``env.task`` ones
    of ``task`` only (default: the default task)."""
    from truckrl.tasks.config import DEFAULT_TASK

    rows = []
    for group, _, section in reference():
        if group.startswith("env.task:") and group != f"env.task:{task or DEFAULT_TASK}":
            continue
        rows += [r for r in section if r[0] == prefix or r[0].startswith(prefix + ".")]
    return rows


class ConfigReference(SphinxDirective):
    """Every config field, one section and table per config; or one table of the fields under
    the argument (module docstring)."""

    has_content = False
    optional_arguments = 1
    option_spec = {"task": directives.unchanged}

    def run(self) -> list[nodes.Node]:
        self.env.note_dependency(__file__)
        docs = self.env.domaindata.setdefault("configref", {"docs": set()})["docs"]
        docs.add(self.env.docname)
        if self.arguments:
            rows = selected(self.arguments[0], self.options.get("task"))
            if not rows:
                raise self.error(f"no config field starts with {self.arguments[0]!r}")
            return [_table(rows)]
        std = self.env.domains.standard_domain
        out: list[nodes.Node] = []
        for group, title, rows in reference():
            node_id = label(group)
            section = nodes.section(ids=[node_id])
            head = "env.task" if group.startswith("env.task:") else group
            words = [nodes.literal(head, head), nodes.Text(title[len(head) :])] if head else []
            section += nodes.title(title, "", *(words or [nodes.Text(title)]))
            prefix = "env.task." if group.startswith("env.task:") else f"{group}." if group else ""
            section += _table(rows, prefix)
            self.state.document.note_explicit_target(section)
            std.note_hyperlink_target(node_id, self.env.docname, node_id, title)
            out.append(section)
        return out


def _always_outdated(app, env, added, changed, removed) -> list[str]:
    """Re-read the pages with the directive on every build: the rows come from the package's
    code, which Sphinx does not track."""
    return sorted(env.domaindata.get("configref", {}).get("docs", set()) - removed)


def _purge(app, env, docname) -> None:
    env.domaindata.get("configref", {}).get("docs", set()).discard(docname)


def _merge(app, env, docnames, other) -> None:
    docs = env.domaindata.setdefault("configref", {"docs": set()})["docs"]
    docs |= other.domaindata.get("configref", {}).get("docs", set())


def setup(app: Sphinx) -> dict:
    app.add_directive("config-reference", ConfigReference)
    app.connect("env-get-outdated", _always_outdated)
    app.connect("env-purge-doc", _purge)
    app.connect("env-merge-info", _merge)
    return {"version": "1", "parallel_read_safe": True, "parallel_write_safe": True}
