"""The docs are a manual: every link into them lands on a heading, every module has its line in the design page, the
results page holds current figures only and stays short, and commit ids stay in the history.

Read from the files (nothing is imported), so a rename anywhere in the repository shows here.
"""

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs"
DESIGN = DOCS / "design.md"
RESULTS = DOCS / "results.md"
HISTORY = DOCS / "history.md"
RESULTS_MAX_LINES = 800

MANUAL = sorted([ROOT / "README.md", *DOCS.rglob("*.md")])
"""The user-facing pages: the README and every page under docs/."""
SOURCES = sorted(
    path
    for path in [
        *MANUAL,
        *(ROOT / "conf").rglob("*.yaml"),
        *(ROOT / "pedrl").rglob("*.py"),
        *(ROOT / "tests").rglob("*.py"),
    ]
    if path != Path(__file__).resolve()
)
"""Every file that may link into the docs: pages, config comments, docstrings (this file's examples aside)."""

ANCHOR_LINK = re.compile(r"([\w./-]*[\w-]+\.md)#([^\s)\]`\"',;:]+)")
SAME_PAGE_LINK = re.compile(r"\]\(#([^)\s]+)\)")
QUOTED_SECTION = re.compile(r"(\w+\.md)`?\)?,?\s+\(?\"([^\"]+)\"")
"""A section named in words: ``docs/results.md, "Learned against greedy"`` or ``results.md ("Routes")``."""
COMMIT_ID = re.compile(r"\b(?=[0-9a-f]*[a-f])(?=[0-9a-f]*[0-9])[0-9a-f]{7,40}\b|\bcommits? [0-9a-f]{7,40}\b")
"""A git commit id: 7 to 40 hex digits with a letter and a digit among them (so no plain number matches), or any
hex run right after the word commit."""
ISSUE_NUMBER = re.compile(r"\bissues? #?\d+", re.IGNORECASE)


def flat(path: Path) -> str:
    """A file's text with the comment markers of wrapped lines removed (``\\n# `` in YAML, ``\\n`` in prose), so a
    link or a quoted section name split over two lines reads as one."""
    return re.sub(r"\n[ \t]*#?[ \t]*", " ", path.read_text())


def slug(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation but ``-`` and ``_`` dropped, spaces as ``-``."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def headings(page: Path) -> list[str]:
    """The headings of a Markdown page (code blocks skipped), in order."""
    text = re.sub(r"```.*?```", "", page.read_text(), flags=re.DOTALL)
    return [line.lstrip("#").strip() for line in text.splitlines() if re.match(r"#{1,6} ", line)]


def anchors(page: Path) -> set[str]:
    """Every anchor a page offers, repeated headings numbered as GitHub numbers them (``-1``, ``-2``)."""
    seen: dict[str, int] = {}
    result = set()
    for heading in headings(page):
        base = slug(heading)
        count = seen.get(base, 0)
        result.add(base if count == 0 else f"{base}-{count}")
        seen[base] = count + 1
    return result


def target(source: Path, name: str) -> Path | None:
    """The page a link in ``source`` names: beside ``source`` (a Markdown link), from the repository root, or, for a
    bare page name, under docs/."""
    for candidate in (source.parent / name, ROOT / name, DOCS / name):
        if candidate.is_file():
            return candidate.resolve()
    return None


def links(source: Path):
    """``(page, anchor)`` for every ``page.md#anchor`` and, in a Markdown page, every ``](#anchor)`` it holds."""
    text = flat(source)
    for match in ANCHOR_LINK.finditer(text):
        yield match.group(1), match.group(2).rstrip(".")
    if source.suffix == ".md":
        for match in SAME_PAGE_LINK.finditer(text):
            yield source.name, match.group(1)


def test_every_link_to_a_docs_anchor_lands_on_a_heading():
    """README, docs, config comments and docstrings: each ``page.md#anchor`` names a page that exists and a heading of
    it (GitHub's anchors)."""
    broken = []
    for source in SOURCES:
        for name, anchor in links(source):
            page = target(source, name)
            where = f"{source.relative_to(ROOT)}: {name}#{anchor}"
            if page is None:
                broken.append(f"{where} (no such page)")
            elif anchor not in anchors(page):
                broken.append(f"{where} (no such heading in {page.relative_to(ROOT)})")
    assert not broken, "links to missing headings:\n" + "\n".join(broken)


def test_the_anchor_check_fails_for_a_heading_that_is_gone(tmp_path):
    """The control: a link to a heading the page does not have is found, one to a heading it has is not."""
    page = tmp_path / "page.md"
    page.write_text("# Title\n\n## The paper's budgets, fused (ε = 0.1)\n\n## Notes\n\n## Notes\n")
    assert anchors(page) == {"title", "the-papers-budgets-fused-ε--01", "notes", "notes-1"}
    source = tmp_path / "source.md"
    source.write_text("[a](page.md#notes-1), [b](page.md#gone) and [c](#nowhere)\n")
    found = {(name, anchor) for name, anchor in links(source)}
    assert found == {("page.md", "notes-1"), ("page.md", "gone"), ("source.md", "nowhere")}
    assert "gone" not in anchors(page) and "notes-1" in anchors(page)


def missing_sections(source: Path) -> list[str]:
    """The sections ``source`` names in words (``docs/results.md, "Learned against greedy"``) that do not start a
    heading of their page (backticks and emphasis aside)."""
    missing = []
    for match in QUOTED_SECTION.finditer(flat(source)):
        name, title = match.groups()
        page = target(source, name)
        if page is None:
            continue
        titles = [re.sub(r"[`*]", "", heading) for heading in headings(page)]
        if not any(heading.startswith(re.sub(r"[`*]", "", title)) for heading in titles):
            missing.append(f'{source.relative_to(ROOT) if source.is_relative_to(ROOT) else source}: {name}, "{title}"')
    return missing


def test_every_section_named_in_words_exists():
    """A section named by its title, in a page, a config comment or a docstring, is the start of a heading of that
    page."""
    broken = [line for source in SOURCES for line in missing_sections(source)]
    assert not broken, "sections named but missing:\n" + "\n".join(broken)


def test_a_section_named_in_words_that_is_gone_is_found(tmp_path):
    """The control: of two sections named in a wrapped YAML comment, the one the page lacks is found."""
    (tmp_path / "page.md").write_text("# Page\n\n## Learned against greedy (the main job)\n")
    source = tmp_path / "room.yaml"
    source.write_text('# see page.md, "Learned against greedy" and page.md,\n# "Measured figures formerly"\nkey: 1\n')
    assert missing_sections(source) == [f'{source}: page.md, "Measured figures formerly"']


@pytest.mark.parametrize("page", MANUAL, ids=lambda page: str(page.relative_to(ROOT)))
def test_no_commit_ids_outside_the_history(page):
    """A reader of the manual does not know the repository's commits: commit ids appear in docs/history.md only."""
    if page == HISTORY:
        assert COMMIT_ID.search(page.read_text()), "the history names the commits it measured"
        return
    found = [match.group(0) for match in COMMIT_ID.finditer(page.read_text())]
    assert not found, f"{page.relative_to(ROOT)} names commits {found}: move that material to docs/history.md"


def test_the_commit_pattern_finds_commits_and_not_numbers():
    assert COMMIT_ID.findall("before e228a3c and 2adfb64, at commit 0150118") == [
        "e228a3c",
        "2adfb64",
        "commit 0150118",
    ]
    assert not COMMIT_ID.findall("agent_frames 1803518, 109,686 trials, 1e-05, defaced, 4096 prototypes")


@pytest.mark.parametrize("page", MANUAL, ids=lambda page: str(page.relative_to(ROOT)))
def test_the_manual_cites_no_issue_numbers(page):
    """Users cite papers and commands; the project's issue tracker is not theirs."""
    found = ISSUE_NUMBER.findall(page.read_text())
    assert not found, f"{page.relative_to(ROOT)} cites {found}"


def broken_tables(text: str) -> list[int]:
    """Line numbers of table rows that follow a line of prose: a paragraph dropped into a table ends it there, and
    the rows after it render as text."""
    lines = text.splitlines()
    return [
        number + 1
        for number, (before, line) in enumerate(zip(["", *lines], lines, strict=False))
        if line.startswith("|") and before.strip() and not before.startswith("|")
    ]


@pytest.mark.parametrize("page", MANUAL, ids=lambda p: str(p.relative_to(ROOT)))
def test_no_table_is_cut_by_a_paragraph(page):
    assert broken_tables(page.read_text()) == [], page.relative_to(ROOT)


def test_a_paragraph_inside_a_table_is_found():
    table = "| a | b |\n|---|---|\n| 1 | 2 |\n"
    assert broken_tables("text\n\n" + table + "\nmore text\n") == []
    assert broken_tables("text\n\n" + table + "cut\n| 3 | 4 |\n") == [7]


def test_the_results_page_holds_current_figures_in_at_most_800_lines():
    """docs/results.md is the reference of what the presets give now; the story and superseded figures live in
    docs/history.md."""
    lines = len(RESULTS.read_text().splitlines())
    assert lines <= RESULTS_MAX_LINES, (
        f"docs/results.md has {lines} lines (at most {RESULTS_MAX_LINES}): move superseded figures to docs/history.md"
    )
    assert "history.md" in RESULTS.read_text()


# ---------------------------------------------------------------------- the design page names every module
def files_block() -> str:
    """The code block of docs/design.md's section "Files"."""
    text = DESIGN.read_text()
    section = text.split("\n### Files\n", 1)[1]
    return section.split("```", 2)[1]


def named_modules(design: str, block: str) -> set[str]:
    """The modules (paths under the repository root) the design page names: a path ``pedrl/x/y.py`` or a dotted name
    ``pedrl.x.y`` anywhere on the page, or, in the Files block, a bare ``y.py`` in the entry of its folder (an entry
    starts at column 0 with ``pedrl/x/`` or ``pedrl/x/z.py``; its continuation lines are indented)."""
    named = set(re.findall(r"\bpedrl/[\w/]+\.py\b", design))
    named |= {dotted.replace(".", "/") + ".py" for dotted in re.findall(r"\bpedrl(?:\.\w+)+", design)}
    for entry in re.split(r"\n(?=\S)", block):
        head = entry.split(maxsplit=1)[0] if entry.strip() else ""
        if not head.startswith("pedrl/"):
            continue
        folder = head if head.endswith("/") else head.rsplit("/", 1)[0] + "/"
        named |= {folder + name for name in re.findall(r"(?<![\w/.])(\w+\.py)\b", entry)}
    return named


def modules() -> list[str]:
    """Every module of the package but the ``__init__.py`` files, as paths under the repository root."""
    paths = (ROOT / "pedrl").rglob("*.py")
    return sorted(str(path.relative_to(ROOT)) for path in paths if path.name != "__init__.py")


def where_to_name(module: str) -> str:
    folder, name = module.rsplit("/", 1)
    return f"add `{name}` to the `{folder}/` entry of the Files block (docs/design.md, ### Files), with what it holds"


@pytest.mark.parametrize("module", modules())
def test_the_design_page_names_every_module(module):
    """docs/design.md is the one description of the layout: a module missing from it is found here, by name."""
    if module not in named_modules(DESIGN.read_text(), files_block()):
        pytest.fail(f"docs/design.md does not name {module}: {where_to_name(module)}", pytrace=False)


def test_a_module_deleted_from_the_design_page_is_missed():
    """The control: deleting the one mention of ``settings.py`` in the vq entry loses pedrl/vq/settings.py, and a bare
    name counts only in its own folder's entry."""
    block = files_block()
    assert "pedrl/vq/settings.py" in named_modules(DESIGN.read_text(), block)
    assert block.count("settings.py") == 1
    without = block.replace("settings.py", "")
    assert "pedrl/vq/settings.py" not in named_modules(DESIGN.read_text().replace(block, without), without)
    assert "pedrl/vq/env.py" not in named_modules("", block)
