"""Sphinx configuration of the truckrl documentation site (``make docs``).

The pages are MyST Markdown in this folder; the API pages are autodoc of the package, and the
configuration reference is generated from the config dataclasses by ``_ext/configref.py``. The
build runs with ``-W --keep-going -n``: every warning, unresolved cross-reference included, fails.
"""

from __future__ import annotations

import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parent
sys.path.insert(0, str(DOCS / "_ext"))  # the local extensions
sys.path.insert(0, str(DOCS.parent))  # the package, importable without installing it

import truckrl  # noqa: E402  (after the path above; cheap: the public names load on use)

project = "truckrl"
author = "the truckrl authors"
copyright = "the truckrl authors, MIT license"
release = version = truckrl.__version__  # written once, in truckrl/__init__.py

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.napoleon",
    "sphinx.ext.viewcode",
    "configref",
    "docstrings",
    "presets",
]

source_suffix = {".md": "markdown"}
root_doc = "index"
# Not pages: working notes, raw logs, the figure scripts' inputs and generated fragments (the
# fragments are pulled into pages with MyST's include directive, which needs no toctree entry).
exclude_patterns = [
    "_build",
    "_generated",
    "notes",
    "gpu_h100",
    "data",
    "media",
    "**/README.md",
]

# ---------------------------------------------------------------------------------------- MyST
myst_enable_extensions = ["colon_fence", "deflist", "dollarmath"]
# Slugs of headings up to this depth are link targets, as on GitHub: `page.md#a-heading`.
myst_heading_anchors = 4

# ------------------------------------------------------------------------------------- autodoc
autodoc_default_options = {"members": True, "member-order": "bysource"}
autodoc_typehints = "description"
autodoc_typehints_description_target = "documented_params"  # types of what the docstring names
autodoc_class_signature = "mixed"
napoleon_google_docstring = True
napoleon_numpy_docstring = False
# Optional packages that the documented modules import lazily or not at all are not mocked:
# everything autodoc imports (torch, tensordict, torchrl, hydra) is a required dependency.

# Module docstrings that a narrative page shows in full; the API pages link there instead
# (_ext/docstrings.py).
docstring_pages = {
    f"truckrl.tasks.{task}.{module}": f"tasks/{task}"
    for task in ("intersection", "dock", "uturn")
    for module in ("task", "scene")
}

# Types of third-party packages: no intersphinx (the build must work offline), so references to
# them cannot resolve; they are shown as plain names instead of failing the nitpicky build.
nitpick_ignore_regex = [
    ("py:.*", r"(torch|tensordict|torchrl|numpy|np|omegaconf|hydra)(\..*)?"),
    ("py:.*", r"(collections|pathlib|os|typing|dataclasses|types|enum)\..*"),
    ("py:.*", r"(Tensor|TensorDict|TensorDictBase|TensorSpec|EnvBase|Generator|ndarray|Module)"),
    ("py:class", r"truckrl\..*\.T"),  # type variables (``T = TypeVar("T")``): not objects
    # Napoleon reads a "Returns:" section's first "text:" as a type; a type name has no space,
    # so such a target is prose, shown as written.
    ("py:class", r".*\s.*"),
]

# ---------------------------------------------------------------------------------------- HTML
html_theme = "furo"
html_title = "truckrl"
html_static_path = ["_static"]
html_css_files = ["custom.css"]
html_show_sourcelink = False
