"""Every ```python block of the manual (the README and the pages under docs/) runs as printed.

The conventions a block of the manual follows (read from the Markdown source; the comments do not render):

- The blocks of one page run in order in one namespace, in a fresh folder: a block may use what an earlier block of
  its page defined (``params``), as a reader typing them in one session would.
- A path literal ending in ``.safetensors`` or ``.sqlite`` names a file the reader has made by then (a policy or a
  checkpoint, a trial of ``pedrl-eval``); the test puts one there first: a seconds-long ``debug=default`` training
  run's checkpoint, a trial of walkers leaving through a door as ``pedrl-eval`` exports it.
- ``<!-- run with: OLD -> NEW; OLD2 -> NEW2 -->`` on the line right before a block runs it with each literal OLD
  (which must occur in it) replaced: a smaller crowd, not a different program.
- ``<!-- not run: REASON -->`` on the line right before a block leaves it out; the reason is required.

Shell blocks do not run, but every ``pedrl-*`` command of a ```bash block must compose its config with its keys
(Hydra's ``compose``, nothing computed).
"""

import re
import shlex
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
import torch
from hydra import compose, initialize_config_dir

from pedrl.analysis import RoomGeometry, Trajectories, trajectories_for_export, write_jupedsim_sqlite
from pedrl.common.commands import CONFIG_DIR
from tests.refusals import train_checkpoint

ROOT = Path(__file__).resolve().parent.parent
MANUAL = sorted([ROOT / "README.md", *(ROOT / "docs").rglob("*.md")])

FENCE = re.compile(r"^```(\w*)[ \t]*\n(.*?)^```[ \t]*$", re.DOTALL | re.MULTILINE)
DIRECTIVE = re.compile(r"<!--\s*(not run|run with)\s*:(.*?)-->\s*\Z", re.DOTALL)
FILE_LITERAL = re.compile(r"""["']([^"'\s]+\.(safetensors|sqlite))["']""")
ENTRY_POINTS = {
    "pedrl-train": "train",
    "pedrl-eval": "eval",
    "pedrl-validate": "validate",
    "pedrl-export": "export",
    "pedrl-plot": "plot",
}
"""The commands whose configs compose from ``conf/`` (``pedrl-sweep`` takes its own arguments)."""


@dataclass(frozen=True)
class Block:
    """A fenced code block of a page: its language, its code, the directive right before it and where it starts."""

    page: Path
    line: int
    language: str
    code: str
    directive: tuple[str, str] | None

    @property
    def label(self) -> str:
        page = self.page.relative_to(ROOT) if self.page.is_relative_to(ROOT) else self.page.name
        return f"{page}:{self.line}"


def blocks(page: Path) -> list[Block]:
    """The fenced code blocks of ``page``, in order."""
    text = page.read_text()
    found = []
    for match in FENCE.finditer(text):
        before = text[: match.start()].rstrip("\n").rsplit("\n", 1)[-1]
        directive = DIRECTIVE.search(before)
        found.append(
            Block(
                page=page,
                line=text.count("\n", 0, match.start()) + 1,
                language=match.group(1),
                code=match.group(2),
                directive=(directive.group(1), directive.group(2).strip()) if directive else None,
            )
        )
    return found


def runnable(block: Block) -> str | None:
    """The code of ``block`` as the test runs it (the replacements of ``run with`` made), None for ``not run``."""
    if block.directive is None:
        return block.code
    kind, text = block.directive
    if kind == "not run":
        assert text, f"{block.label}: '<!-- not run: -->' needs a reason"
        return None
    code = block.code
    for replacement in text.split(";"):
        old, arrow, new = replacement.partition("->")
        assert arrow and old.strip(), f"{block.label}: 'run with' takes 'OLD -> NEW' pairs, got {replacement!r}"
        assert old.strip() in code, f"{block.label}: 'run with' replaces {old.strip()!r}, which the block lacks"
        code = code.replace(old.strip(), new.strip())
    return code


PYTHON_PAGES = [page for page in MANUAL if any(b.language == "python" for b in blocks(page))]


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory) -> Path:
    return train_checkpoint(tmp_path_factory)


def exported_trial(path: Path) -> None:
    """A trial of 6 walkers leaving through the door of a 20 m x 30 m room, written as ``pedrl-eval`` exports it."""
    geometry = RoomGeometry(width=20.0, length=30.0, door_width=2.0)
    start = np.stack([np.linspace(9.3, 10.7, 6), np.linspace(12.0, 27.0, 6)], axis=-1)
    positions = start[None] + np.arange(20)[:, None, None] * np.array([0.0, 2.5])
    passed = positions[..., 1] >= geometry.length
    active = ~passed | (passed & (np.cumsum(passed, axis=0) == 1))
    velocities = np.broadcast_to(np.array([0.0, 2.5]), positions.shape).copy()
    trial = Trajectories(positions, velocities, active, 1.0, geometry)
    write_jupedsim_sqlite(path, trajectories_for_export(trial))


def run_page(page: Path, folder: Path, checkpoint: Path | None) -> int:
    """Run the python blocks of ``page`` in ``folder`` (the current folder), in one namespace, the files they name
    made first: the number of blocks run; an ``AssertionError`` naming the first block that fails."""
    threads = torch.get_num_threads()
    namespace: dict = {"__name__": "__main__"}
    ran = 0
    try:
        for block in blocks(page):
            code = runnable(block) if block.language == "python" else None
            if code is None:
                continue
            for literal, suffix in FILE_LITERAL.findall(code):
                target = folder / literal
                if not target.exists():
                    target.parent.mkdir(parents=True, exist_ok=True)
                    if suffix == "sqlite":
                        exported_trial(target)
                    else:
                        assert checkpoint is not None, f"{block.label} needs a checkpoint"
                        shutil.copyfile(checkpoint, target)
            try:
                exec(compile(code, block.label, "exec"), namespace)
            except Exception as err:
                raise AssertionError(f"the block at {block.label} failed: {type(err).__name__}: {err}") from err
            ran += 1
    finally:
        torch.set_num_threads(threads)
    return ran


@pytest.mark.parametrize("page", PYTHON_PAGES, ids=lambda page: str(page.relative_to(ROOT)))
def test_every_python_block_of_the_page_runs(page, checkpoint, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    python = [block for block in blocks(page) if block.language == "python"]
    assert run_page(page, tmp_path, checkpoint) == sum(runnable(block) is not None for block in python) >= 1


def test_a_failing_block_and_a_bad_directive_are_caught(tmp_path, monkeypatch):
    """The control: the manual's PedPy snippet as it was (a str path, which PedPy 1.5 refuses) fails, and so do a
    ``not run`` without a reason and a ``run with`` whose text the block lacks."""
    pytest.importorskip("pedpy")
    monkeypatch.chdir(tmp_path)
    old_snippet = tmp_path / "old.md"
    old_snippet.write_text(
        '```python\nimport pedpy\npath = "outputs/my_room/trajectories/agents_60/trial_000.sqlite"\n'
        "trajectory = pedpy.load_trajectory_from_jupedsim_sqlite(trajectory_file=path)\n```\n"
    )
    with pytest.raises(AssertionError, match=r"the block at old.md:1 failed"):
        run_page(old_snippet, tmp_path, None)
    fixed = tmp_path / "fixed.md"
    fixed.write_text(
        old_snippet.read_text()
        .replace('path = "', "path = __import__('pathlib').Path(\"", 1)
        .replace('.sqlite"', '.sqlite")', 1)
    )
    assert run_page(fixed, tmp_path, None) == 1

    page = tmp_path / "page.md"
    page.write_text(
        "<!-- not run: -->\n```python\nx = 1\n```\n"
        "<!-- run with: 20_000 -> 200 -->\n```python\nn = 300\n```\n"
        "<!-- run with: 300 -> 3 -->\n```python\nn = 300\n```\n"
        "<!-- not run: needs a GPU -->\n```python\nraise SystemExit\n```\n"
    )
    first, second, third, fourth = blocks(page)
    with pytest.raises(AssertionError, match="needs a reason"):
        runnable(first)
    with pytest.raises(AssertionError, match="which the block lacks"):
        runnable(second)
    assert runnable(third) == "n = 3\n" and runnable(fourth) is None


def shell_commands(page: Path) -> list[tuple[str, list[str]]]:
    """The ``pedrl-*`` commands of the shell blocks of ``page``: the command and its overrides (``hydra.*`` aside)."""
    commands = []
    for block in blocks(page):
        if block.language not in ("bash", "sh", "shell", "console"):
            continue
        for line in block.code.replace("\\\n", " ").splitlines():
            words = shlex.split(line, comments=True)
            if words and words[0] in ENTRY_POINTS:
                commands.append((words[0], [w for w in words[1:] if "=" in w and not w.startswith("hydra.")]))
    return commands


@pytest.mark.parametrize("page", MANUAL, ids=lambda page: str(page.relative_to(ROOT)))
def test_the_pedrl_commands_of_shell_blocks_compose(page):
    for command, overrides in shell_commands(page):
        with initialize_config_dir(version_base="1.3", config_dir=str(CONFIG_DIR)):
            try:
                compose(ENTRY_POINTS[command], overrides)
            except Exception as err:
                raise AssertionError(f"{page.name}: {command} {' '.join(overrides)}: {err}") from err


def test_the_shell_blocks_are_read():
    """The control of the test above: the manual's shell blocks hold commands, and a key that is none is refused."""
    assert sum(len(shell_commands(page)) for page in MANUAL) >= 20
    with initialize_config_dir(version_base="1.3", config_dir=str(CONFIG_DIR)), pytest.raises(Exception, match="nope"):
        compose("eval", ["export.nope=1"])
