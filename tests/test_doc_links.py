"""Markdown files link only inside the repository.

A clone has nothing beside its root: a link such as ``../shared/DESIGN.md`` works on the machine
it was written on and is dead everywhere else. Every tracked ``*.md`` is read; each relative link
(inline, image, reference definition or HTML ``href``/``src``) must resolve inside the repository
to a file or directory that exists, and no text may name ``../shared``.
"""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

#: Link targets in markdown: ``[text](target "title")``, ``![alt](target)``, ``[id]: target``
#: and HTML attributes. The target is the first space-free run (a title may follow).
LINK_PATTERNS = (
    re.compile(r"!?\[[^\]]*\]\(\s*<?([^)\s>]+)>?[^)]*\)"),
    # (a definition's target is all the line holds but an optional title: "[a, b]: 95 % ..." is
    # prose, as CommonMark renders it)
    re.compile(r"""^\s{0,3}\[[^\]]+\]:[ \t]*<?([^\s>]+)>?[ \t]*(?:["'(].*)?$""", re.MULTILINE),
    re.compile(r"""\b(?:href|src)\s*=\s*["']([^"']+)["']"""),
)
#: Code is shown, not followed: fenced blocks and inline code spans are dropped before links
#: are looked for (``../shared`` is looked for everywhere).
FENCED = re.compile(r"^(```|~~~).*?^\1", re.MULTILINE | re.DOTALL)
INLINE_CODE = re.compile(r"`[^`\n]*`")
SCHEME = re.compile(r"^[A-Za-z][A-Za-z0-9+.-]*:")  # http:, https:, mailto:, data: ...


def tracked_markdown(root: Path) -> list[Path]:
    """The repository's ``*.md`` files: git's tracked ones and new ones it does not ignore, or
    (no git) every one outside hidden directories."""
    try:
        out = subprocess.run(
            ["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard", "--", "*.md"],
            cwd=root,
            capture_output=True,
            check=True,
            text=True,
        ).stdout
        files = [root / name for name in out.split("\0") if name]
    except (OSError, subprocess.CalledProcessError):
        files = [
            p
            for p in root.rglob("*.md")
            if not any(part.startswith(".") for part in p.relative_to(root).parts)
        ]
    return sorted(p for p in files if p.is_file())


def link_targets(text: str) -> list[str]:
    prose = INLINE_CODE.sub("", FENCED.sub("", text))
    return [m.group(1) for pattern in LINK_PATTERNS for m in pattern.finditer(prose)]


def link_problems(md: Path, root: Path) -> list[str]:
    """What is wrong with ``md``'s links, one line each (empty: nothing)."""
    text = md.read_text(encoding="utf-8")
    name = md.relative_to(root).as_posix()
    problems = [
        f"{name}:{text.count(chr(10), 0, m.start()) + 1}: names ../shared (not in a clone)"
        for m in re.finditer(r"\.\./shared\b", text)
    ]
    for target in link_targets(text):
        if SCHEME.match(target) or target.startswith("#"):
            continue  # a URL, or an anchor in the same file
        path = target.split("#", 1)[0].split("?", 1)[0]
        # A leading / is the repository root (as GitHub renders it), never the machine's root.
        base = root if path.startswith("/") else md.parent
        resolved = (base / path.lstrip("/")).resolve()
        if not resolved.is_relative_to(root):
            problems.append(f"{name}: link {target!r} leads outside the repository")
        elif not resolved.exists():
            problems.append(f"{name}: link {target!r} points to nothing")
    return problems


def test_markdown_links_stay_inside_the_repository():
    files = tracked_markdown(ROOT)
    assert ROOT / "README.md" in files and (ROOT / "docs" / "design.md").is_file()
    problems = [line for md in files for line in link_problems(md, ROOT)]
    assert not problems, "\n".join(problems)


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("see [design](../../elsewhere/DESIGN.md)", "leads outside the repository"),
        ("see [design](../docs/nosuch.md#x)", "points to nothing"),
        ("[ref]: ../../outside.md", "leads outside the repository"),
        ("[ref]: ../nosuch.md 'a title'", "points to nothing"),
        ("[low, high]: 95 % interval\n[x](../../y.md)", "leads outside the repository"),
        ('<img src="../../x.png">', "leads outside the repository"),
        ("read `../shared/DESIGN.md` first", "names ../shared"),
        ("[root file](/nosuch.md)", "points to nothing"),
    ],
)
def test_escaping_and_dead_links_are_caught(tmp_path, text, expected):
    (tmp_path / "docs").mkdir()
    md = tmp_path / "docs" / "page.md"
    md.write_text(text + "\n", encoding="utf-8")
    problems = link_problems(md, tmp_path)
    assert len(problems) == 1 and expected in problems[0], problems


def test_urls_anchors_code_and_inside_links_pass(tmp_path):
    (tmp_path / "docs").mkdir()
    (tmp_path / "docs" / "other.md").write_text("x\n", encoding="utf-8")
    md = tmp_path / "docs" / "page.md"
    md.write_text(
        "[web](https://example.org/a) [mail](mailto:a@b.c) [here](#top) [other](other.md#s)\n"
        "[up](../docs/other.md) ![img](other.md 'title') [root](/docs/other.md)\n"
        "```python\nx = f[0](../../../etc)\n```\n"
        "inline `[a](../../../b)` code\n",
        encoding="utf-8",
    )
    assert link_problems(md, tmp_path) == []
