"""Sphinx directive ``presets``: the Hydra preset files of a folder, each shown as it is.

The presets explain themselves in their comments; the pages show the files instead of
paraphrasing them, so a changed or added preset is on the site at the next build. The argument is
a folder relative to the repository root; every ``<group>/<name>.yaml`` below it becomes a rubric
``<group>=<name>`` (the command-line choice) and the file's text. ``:groups:`` limits and orders
the groups (default: all, sorted). A folder without presets is an error, so a moved folder fails
the build instead of leaving an empty section.

    ```{presets} truckrl/tasks/dock/conf
    ```
"""

from __future__ import annotations

from pathlib import Path

from docutils import nodes
from docutils.parsers.rst import directives
from sphinx.util.docutils import SphinxDirective

ROOT = Path(__file__).resolve().parents[2]  # the repository: docs/_ext/ -> docs/ -> root


def preset_files(folder: Path, groups: list[str] | None) -> list[tuple[str, Path]]:
    """``(group=name, file)`` of the ``<group>/<name>.yaml`` files below ``folder``."""
    names = groups or sorted(p.name for p in folder.iterdir() if p.is_dir())
    out = []
    for group in names:
        for path in sorted((folder / group).glob("*.yaml")):
            out.append((f"{group}={path.stem}", path))
    return out


class Presets(SphinxDirective):
    """The preset files below a folder (module docstring)."""

    required_arguments = 1
    option_spec = {"groups": directives.unchanged}

    def run(self) -> list[nodes.Node]:
        folder = ROOT / self.arguments[0]
        groups = self.options.get("groups", "").split() or None
        files = preset_files(folder, groups) if folder.is_dir() else []
        if not files:
            raise self.error(f"no <group>/<name>.yaml presets under {self.arguments[0]}")
        out: list[nodes.Node] = []
        for choice, path in files:
            self.env.note_dependency(str(path))
            text = path.read_text(encoding="utf-8").rstrip("\n")
            rel = path.relative_to(ROOT).as_posix()
            rubric = nodes.rubric("", "", nodes.literal(choice, choice), nodes.Text(f"  ({rel})"))
            block = nodes.literal_block(text, text, language="yaml")
            out += [rubric, block]
        return out


def setup(app) -> dict:
    app.add_directive("presets", Presets)
    return {"version": "1", "parallel_read_safe": True, "parallel_write_safe": True}
