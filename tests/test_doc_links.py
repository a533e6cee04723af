"""Every relative link in the checkout's Markdown points at a file (or folder) that exists,
and a link's #anchor at a heading of the page it names: a page or a study moved leaves no
dangling link behind. Links inside code (fenced blocks, `spans`) are text, not links;
absolute URLs (http:, mailto:, ...) are not checked."""
import re
import subprocess
from pathlib import Path
from urllib.parse import unquote

import pytest

ROOT = Path(__file__).resolve().parents[1]

FENCE = re.compile(r"^ {0,3}(```|~~~)")
CODE_SPAN = re.compile(r"(`+)(?:(?!\1).)+?\1")
# [text](target "title") and ![alt](target); the text may hold one level of brackets
INLINE = re.compile(r"!?\[(?:[^\[\]]|\[[^\]]*\])*\]\(\s*(<[^>]*>|[^)\s]+)(?:\s+\"[^\"]*\")?\s*\)")
REFERENCE = re.compile(r"^ {0,3}\[[^\]]+\]:\s*(\S+)")
SCHEME = re.compile(r"^[a-zA-Z][a-zA-Z0-9+.-]*:")


def markdown_files(root: Path = ROOT) -> list[Path]:
    """The checkout's Markdown: tracked files and new ones git does not ignore."""
    try:
        out = subprocess.run(["git", "ls-files", "-z", "--cached", "--others",
                              "--exclude-standard", "--", "*.md"], cwd=root,
                             capture_output=True, text=True, check=True).stdout
    except (OSError, subprocess.CalledProcessError):
        pytest.skip("not a git checkout: no list of tracked files")
    return sorted({root / name for name in out.split("\0") if name and (root / name).is_file()})


def links(text: str) -> list[tuple[int, str]]:
    """(line number, target) of every link outside code; a link's text may span lines."""
    prose, fenced = [], None
    for line in text.splitlines():
        fence = FENCE.match(line)
        if fence:
            if fenced is None:
                fenced = fence.group(1)
            elif fence.group(1) == fenced:
                fenced = None
            prose.append("")
        else:
            prose.append("" if fenced is not None else CODE_SPAN.sub("", line))
    found = []
    for number, line in enumerate(prose, 1):
        ref = REFERENCE.match(line)
        if ref:
            found.append((number, ref.group(1)))
    joined = "\n".join(prose)
    for m in INLINE.finditer(joined):
        found.append((joined.count("\n", 0, m.start(1)) + 1, m.group(1).strip("<>")))
    return sorted(found)


def slug(heading: str) -> str:
    """GitHub's anchor for a heading: lower case, markup and punctuation dropped but for
    hyphens and underscores, spaces to hyphens."""
    text = re.sub(r"!?\[([^\]]*)\]\([^)]*\)", r"\1", heading)      # a link: its text
    text = re.sub(r"[`*]|<[^>]+>", "", text).strip().lower()
    text = re.sub(r"[^\w\- ]", "", text)
    return text.replace(" ", "-")


def anchors(path: Path) -> set[str]:
    """The anchors of a page's headings (a repeated one gets -1, -2, ... as on GitHub)."""
    seen: dict[str, int] = {}
    out, fenced = set(), None
    for line in path.read_text(encoding="utf-8").splitlines():
        fence = FENCE.match(line)
        if fence:
            fenced = fence.group(1) if fenced is None else (None if fence.group(1) == fenced
                                                            else fenced)
            continue
        heading = re.match(r"^ {0,3}#{1,6}\s+(.*?)\s*#*\s*$", line)
        if fenced is None and heading:
            base = slug(heading.group(1))
            n = seen.get(base, 0)
            seen[base] = n + 1
            out.add(base if n == 0 else f"{base}-{n}")
    return out


def broken_links(root: Path = ROOT) -> list[str]:
    """'page:line: target (why)' for each relative link that leads nowhere."""
    bad = []
    for page in markdown_files(root):
        for number, target in links(page.read_text(encoding="utf-8")):
            if SCHEME.match(target) or target.startswith("//"):
                continue
            path, _, anchor = target.partition("#")
            path = unquote(path)
            if path:
                dest = (root / path.lstrip("/")) if path.startswith("/") else page.parent / path
            else:
                dest = page
            where = f"{page.relative_to(root)}:{number}: {target}"
            if not dest.exists():
                bad.append(f"{where} (no such file)")
            elif not dest.resolve().is_relative_to(root.resolve()):
                bad.append(f"{where} (outside the checkout)")
            elif anchor and dest.is_file() and dest.suffix == ".md" \
                    and unquote(anchor).lower() not in anchors(dest):
                bad.append(f"{where} (no heading #{anchor})")
    return bad


def test_every_relative_link_in_the_markdown_resolves():
    bad = broken_links()
    assert not bad, "links to nothing:\n" + "\n".join(bad)


def test_the_checker_sees_a_broken_link_and_an_anchor(tmp_path):
    subprocess.run(["git", "init", "-q", str(tmp_path)], check=True)
    (tmp_path / "docs").mkdir()
    (tmp_path / "docs" / "a.md").write_text(
        "# A page\n\n## Why it's here (issue 1)\n\nSee [b](b.md), [gone](gone.md),\n"
        "[up](../README.md#top), [why](#why-its-here-issue-1), [no](#nowhere),\n"
        "![fig](figures/x.png), `[code](code.md)`, [web](https://example.com/x.md).\n"
        "```\n[fenced](fenced.md)\n```\n[ref]: c.md\n")
    (tmp_path / "docs" / "b.md").write_text("# B\n")
    (tmp_path / "README.md").write_text("# Top\n")
    bad = broken_links(tmp_path)
    assert bad == ["docs/a.md:5: gone.md (no such file)",
                   "docs/a.md:6: #nowhere (no heading #nowhere)",
                   "docs/a.md:7: figures/x.png (no such file)",
                   "docs/a.md:11: c.md (no such file)"], bad
