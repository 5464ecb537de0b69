"""The documentation cannot rot: the README's Python examples run and print what the README says they print,
and every relative link in README.md, CHANGELOG.md and docs/*.md points at a file of the repository."""

import re
import subprocess
import sys
from pathlib import Path

import pytest

from _compile_flags import user_environment

REPO = Path(__file__).resolve().parents[1]
README = REPO / "README.md"
PAGES = [README, REPO / "CHANGELOG.md", *sorted((REPO / "docs").glob("*.md"))]

_LINK = re.compile(r"\[[^\]]*\]\(([^)\s]+)\)")
_PYTHON_BLOCK = re.compile(r"^```python\n(.*?)^```", re.DOTALL | re.MULTILINE)


def relative_links(markdown: str) -> list[str]:
    """Targets of the Markdown links and images that are paths in the repository (no scheme, no bare anchor),
    without their ``#anchor``."""
    targets = (m.group(1) for m in _LINK.finditer(markdown))
    return [t.split("#")[0] for t in targets if not re.match(r"[a-z][a-z0-9+.-]*:|#", t)]


@pytest.mark.slow
@pytest.mark.parametrize("number", [0, 1])
def test_readme_example_runs_and_prints_what_the_readme_says(number):
    readme = README.read_text()
    examples = _PYTHON_BLOCK.findall(readme)
    assert len(examples) == 2, "the README has two Python examples: the pipeline, then triangulation"
    # A fresh interpreter with the project's configuration, as a user pastes the example (tests/_compile_flags.py).
    run = subprocess.run([sys.executable, "-c", examples[number]], cwd=REPO, capture_output=True, text=True,
                         env=user_environment(PYTHONPATH=str(REPO)))
    assert run.returncode == 0, run.stderr[-3000:]
    lines = run.stdout.splitlines()
    assert lines, "the README example prints nothing"
    for line in lines:
        assert f"`{line}`" in readme, f"the README example printed {line!r}, which the README does not quote"


def test_link_finder_sees_the_readme_links():
    links = relative_links(README.read_text())
    assert {"docs/protocols.md", "docs/jcsat.md", "docs/figures/shelf_frame.png", "LICENSE"} <= set(links)
    assert relative_links("[a](https://x.org/y.md) [b](#top) [c](docs/c.md#part) ![d](e.png)") == ["docs/c.md", "e.png"]


@pytest.mark.parametrize("page", PAGES, ids=[p.relative_to(REPO).as_posix() for p in PAGES])
def test_relative_links_point_at_files(page):
    missing = [t for t in relative_links(page.read_text()) if not (page.parent / t).exists()]
    assert not missing, f"{page.relative_to(REPO)} links to missing files: {missing}"
