"""Every code block the README and docs mark runnable runs, from the repository root, and
does not fail: a page's opening example is the first thing a reader copies.

A block is marked by its info string, ```` ```python runnable ````: Markdown renderers
highlight it as Python and ignore the second word. Each runs in a fresh interpreter (its
own imports, nothing shared between blocks) with a time limit."""
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BLOCK = re.compile(r"^```python runnable[ \t]*\n(.*?)^```[ \t]*$", re.S | re.M)
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]


def runnable_blocks() -> list[tuple[str, str]]:
    """(page:line, code) of every runnable block of PAGES."""
    found = []
    for page in PAGES:
        text = page.read_text()
        for m in BLOCK.finditer(text):
            line = text.count("\n", 0, m.start()) + 1
            found.append((f"{page.relative_to(ROOT)}:{line}", m.group(1)))
    return found


def test_the_product_pages_open_with_a_runnable_example():
    marked = {where.split(":")[0] for where, _ in runnable_blocks()}
    for page in ("runtime", "dvs", "sensors", "envs", "formats", "view"):
        assert f"docs/{page}.md" in marked, f"docs/{page}.md has no runnable example"
        text = (ROOT / "docs" / f"{page}.md").read_text()
        first_block = text.find("```")
        assert text.startswith("```python runnable", first_block), \
            f"docs/{page}.md: its first code block is not the runnable example"


@pytest.mark.parametrize("where, code", runnable_blocks(), ids=lambda v: v if ":" in v else "")
def test_a_runnable_block_runs(where, code):
    done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True,
                          text=True, timeout=180)
    assert done.returncode == 0, f"{where}:\n{done.stdout[-1500:]}\n{done.stderr[-3000:]}"


def test_the_answer_is_on_the_first_screen():
    """The README's first 25 lines hold both make commands and the answer with its link;
    docs/results.md's first 40 lines hold the verdict table."""
    readme = (ROOT / "README.md").read_text().splitlines()[:25]
    text = "\n".join(readme)
    assert "make demo" in text and "make test" in text
    assert "**Does an event camera help?**" in text and "(docs/results.md)" in text
    results = "\n".join((ROOT / "docs" / "results.md").read_text().splitlines()[:40])
    assert "| task | rate | events ahead | no clear difference | events behind |" in results
