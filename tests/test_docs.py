"""The documentation site: its Sphinx extensions, its link checking, and the full build.

The fast tests build small throwaway sites with the site's own configuration (``-c docs``), so
they check what ``make docs`` relies on (a broken internal link fails the build; the generated
configuration tables hold the code's defaults) in seconds. The full build of ``docs/`` with
``-W -n`` and the getting-started examples take minutes on a small machine: they are ``slow``,
and CI's ``make docs`` builds the site on every run.
"""

from __future__ import annotations

import contextlib
import io
import re
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("sphinx")
pytest.importorskip("myst_parser")

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
sys.path.insert(0, str(DOCS / "_ext"))

import configref  # noqa: E402  (docs/_ext, put on the path above)
import docstrings  # noqa: E402


def sphinx_build(srcdir: Path, outdir: Path, *opts: str) -> subprocess.CompletedProcess:
    """``sphinx-build -b html`` of ``srcdir`` with the site's conf.py, warnings as errors."""
    cmd = [sys.executable, "-m", "sphinx", "-b", "html", "-c", str(DOCS), "-W", "--keep-going"]
    cmd += ["-n", "-q", *opts, str(srcdir), str(outdir)]
    return subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, timeout=900)


def small_site(tmp_path: Path, pages: dict[str, str]) -> Path:
    src = tmp_path / "src"
    src.mkdir()
    for name, text in pages.items():
        (src / f"{name}.md").write_text(text)
    return src


INDEX = "# Home\n\n```{toctree}\nother\n```\n\n"
OTHER = "# Other\n\n## A heading\n\nText.\n"


GOOD_LINKS = "[page](other.md) [heading](other.md#a-heading) [here](#home)\n"
TABLES = "```{config-reference} env.lidar\n```\n\n```{config-reference} env.task.reward\n"
TABLES += ":task: dock\n```\n"


def table_cells(html: str) -> dict[str, list[str]]:
    """``{first cell: cells}`` of every body row of the tables in ``html``."""
    cells = {}
    for row in re.findall(r"<tr[^>]*>(.*?)</tr>", html, re.S):
        text = [re.sub(r"<[^>]+>", "", c).strip() for c in re.findall(r"<td.*?</td>", row, re.S)]
        if text:
            cells[text[0]] = text
    return cells


def test_small_site_builds_clean_with_generated_tables(tmp_path):
    """Good links build without a warning (the control for the broken-target test), and a
    ``{config-reference}`` table shows each field's default, unit and range from the code."""
    from truckrl.sim.lidar import LidarConfig

    src = small_site(tmp_path, {"index": INDEX + GOOD_LINKS, "other": OTHER + TABLES})
    result = sphinx_build(src, tmp_path / "out")
    assert result.returncode == 0, result.stderr
    cells = table_cells((tmp_path / "out" / "other.html").read_text())
    assert cells["env.lidar.num_beams"][1] == str(LidarConfig().num_beams)
    assert cells["env.lidar.max_range"][2] == "m"
    assert "env.task.reward.progress" in cells  # the dock task's weights
    assert "env.task.reward.tractor_heading" not in cells  # the intersection task's only


#: Broken internal targets and the part of the warning that names each.
BROKEN = {
    "[gone](missing.md)": "missing.md",
    "[gone](other.md#no-such-heading)": "no-such-heading",
    "[gone](#no-such-anchor)": "no-such-anchor",
    "[gone](missing.png)": "missing.png",
    "```{config-reference} env.no_such_group\n```": "env.no_such_group",
}


def test_broken_internal_targets_fail_the_build(tmp_path):
    """A link to a missing page, heading anchor or file, a page outside every toctree and a
    config table of no field are warnings, so ``-W`` fails, naming each."""
    page = INDEX + "\n\n".join(BROKEN) + "\n"
    src = small_site(tmp_path, {"index": page, "other": OTHER, "stray": "# Stray\n"})
    result = sphinx_build(src, tmp_path / "out")
    assert result.returncode != 0
    for message in BROKEN.values():
        assert message in result.stderr, result.stderr
    assert re.search(r"stray.*toctree", result.stderr), result.stderr


def test_config_reference_lists_what_tools_configs_prints():
    """The generated reference and ``truckrl tools configs`` show the same fields."""
    from truckrl.config.schemas import main

    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        assert main([]) == 0
    printed = {line.split()[0] for line in out.getvalue().splitlines() if line.strip()}
    sections = configref.reference()
    shown = {row[0] for _, _, rows in sections for row in rows}
    assert shown == printed
    groups = [group for group, _, _ in sections]
    assert len(groups) == len(set(groups))
    assert {"env.vehicle", "ppo", "env.task:dock", "env.task:uturn"} <= set(groups)


@pytest.mark.parametrize(
    "line, expected",
    [
        ("Smallest |sin| of the angle", r"Smallest \|sin\| of the angle"),
        ("``|alpha|`` stays a literal", "``|alpha|`` stays a literal"),
        ("| a line block", "| a line block"),
        ("+-----+-----+", "+-----+-----+"),
        ("speed | accel | jerk", "speed | accel | jerk"),
    ],
)
def test_absolute_values_are_not_substitutions(line, expected):
    assert docstrings._bars(line) == expected


@pytest.mark.slow
def test_site_builds_without_warnings(tmp_path):
    """The whole site, as ``make docs`` builds it: ``-W --keep-going -n`` and no warning."""
    render = DOCS / "render.py"
    if render.exists():
        subprocess.run([sys.executable, str(render)], cwd=ROOT, check=True, timeout=300)
    result = sphinx_build(DOCS, tmp_path / "html", "-d", str(tmp_path / "doctrees"))
    assert result.returncode == 0, result.stderr
    assert "WARNING" not in result.stderr and "ERROR" not in result.stderr, result.stderr
    for page in ("index", "environment", "configuration", "api/env", "tasks/dock"):
        assert (tmp_path / "html" / f"{page}.html").exists()


def python_blocks(page: str) -> list[str]:
    return re.findall(r"```python\n(.*?)```", (DOCS / page).read_text(), re.S)


@pytest.mark.slow
@pytest.mark.parametrize("index", range(len(python_blocks("getting-started.md"))))
def test_getting_started_examples_run(tmp_path, index):
    """Every Python example of the getting-started page runs as written."""
    code = python_blocks("getting-started.md")[index]
    result = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path, timeout=1200
    )
    assert result.returncode == 0, result.stderr
