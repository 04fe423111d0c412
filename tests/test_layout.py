"""The module layout (issue 12): entry points import library modules only, and the room stays free of Hydra and I/O.

The layout itself, package by package, is described once, in docs/design.md (section Layout).

Read from the source with ``ast`` (nothing is imported), so that an import inside a function counts as well.
"""

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parent.parent / "pedrl"
ENTRY_POINTS = ("pedrl.train", "pedrl.evaluate", "pedrl.validate", "pedrl.plot", "pedrl.sweep", "pedrl.export")
SIM_FORBIDDEN = ("hydra", "omegaconf", "pedrl.io", "shapely", "pedrl.scenarios")
"""What pedrl/sim/ never imports: no config framework, and none of pedrl.io's file I/O (checkpoints, CSV, logs)."""
CLI = "pedrl.cli"
"""The Hydra pieces the entry points share; what a ``python -m`` tool needs too is on the floor."""
FLOOR = "pedrl.common"
"""The bottom of the layering (argument checks, one-line errors, the tools' argparse helpers): every layer may import
it, and it imports nothing else of pedrl, nor Hydra."""


def module_name(path: Path, root: Path = PACKAGE.parent) -> str:
    """The dotted name of the module at ``path``, relative to the folder ``root`` that holds the package."""
    parts = path.relative_to(root).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imported_modules(path: Path, root: Path = PACKAGE.parent, *, runtime_only: bool = False) -> set[str]:
    """Every module ``path`` imports, anywhere in the file, by its absolute name; ``from a import b`` counts as
    both ``a`` and ``a.b`` (``b`` may be a module). ``runtime_only`` leaves out the imports under
    ``if TYPE_CHECKING:``, which never run."""
    package = module_name(path, root).split(".")
    if path.name != "__init__.py":
        package = package[:-1]
    names = set()
    tree = ast.parse(path.read_text(), filename=str(path))
    if runtime_only:
        for node in ast.walk(tree):
            if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
                node.body = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = ".".join(package[: len(package) - node.level + 1] if node.level else [])
            module = ".".join(part for part in (base, node.module or "") if part)
            names.add(module)
            names.update(f"{module}.{alias.name}" for alias in node.names)
    return names


def within(name: str, modules: tuple[str, ...]) -> bool:
    return any(name == module or name.startswith(f"{module}.") for module in modules)


def entry_point_path(name: str) -> Path:
    return PACKAGE.parent / f"{name.replace('.', '/')}.py"


def test_the_import_reader_sees_imports_inside_functions_and_relative_ones(tmp_path):
    (tmp_path / "pedrl" / "sim").mkdir(parents=True)
    sample = tmp_path / "pedrl" / "sim" / "sample.py"
    sample.write_text("import os\n\ndef f():\n    from pedrl import train\n    from ..io import files\n")
    names = imported_modules(sample, root=tmp_path)
    assert {"os", "pedrl.train", "pedrl.io", "pedrl.io.files"} <= names
    # every entry point shares pedrl.cli (pedrl.sweep imports it inside a function)
    for entry_point in ENTRY_POINTS:
        assert "pedrl.cli" in imported_modules(entry_point_path(entry_point)), entry_point


@pytest.mark.parametrize("entry_point", ENTRY_POINTS)
def test_entry_points_do_not_import_each_other(entry_point):
    """What two entry points share lives in a library module (pedrl.runtime, pedrl.learning_curves,
    pedrl.evaluation), so that each entry point stays a thin wrapper."""
    imports = imported_modules(entry_point_path(entry_point))
    others = [name for name in sorted(imports) if within(name, ENTRY_POINTS)]
    assert not others, f"{entry_point} imports the entry point(s) {others}"


@pytest.mark.parametrize("path", sorted((PACKAGE / "sim").rglob("*.py")), ids=lambda p: p.name)
def test_sim_imports_neither_hydra_nor_omegaconf_nor_io_nor_shapely(path):
    """The simulation is pure tensor code: polygons are built into tensors by pedrl.scenarios, which uses shapely."""
    forbidden = [name for name in sorted(imported_modules(path)) if within(name, SIM_FORBIDDEN)]
    assert not forbidden, f"{module_name(path)} imports {forbidden}"


def pedrl_modules() -> dict[str, Path]:
    """Every module of the package, by its dotted name."""
    return {module_name(path): path for path in sorted(PACKAGE.rglob("*.py"))}


def test_only_the_entry_points_import_pedrl_cli():
    """Hydra's pieces stay with the entry points: a library module or a ``python -m`` tool that imported
    pedrl.cli would pull the entry points' layer below them (pedrl.evaluation.config once did, for the run folder)."""
    users = sorted(name for name, path in pedrl_modules().items() if CLI in imported_modules(path))
    assert users, "the reader found no user of pedrl.cli"
    below = [name for name in users if name not in ENTRY_POINTS and name != CLI]
    assert not below, f"{below} import {CLI}: only the entry points {ENTRY_POINTS} may"


def test_the_floor_imports_nothing_of_pedrl_above_it():
    floor = {name: path for name, path in pedrl_modules().items() if within(name, (FLOOR,))}
    assert {f"{FLOOR}.checks", f"{FLOOR}.commands"} <= set(floor), f"{FLOOR} misses its modules"
    for name, path in floor.items():
        imports = imported_modules(path)
        above = sorted(n for n in imports if within(n, ("pedrl",)) and not within(n, (FLOOR,)))
        assert not above, f"{name} imports {above}: the floor imports nothing else of pedrl"
        hydra = sorted(n for n in imports if within(n, ("hydra", "omegaconf")))
        assert not hydra, f"{name} imports {hydra}: Hydra's pieces are in {CLI}"


def test_the_argument_checks_are_imported_from_the_floor():
    """The one-line checks of user values (``check_integer``, ``check_memory``, ...) are on the floor, not in
    pedrl.sim: a trainer, a file reader or a tool that checks a value does not depend on the simulation for it."""
    from_sim = sorted(name for name, path in pedrl_modules().items() if "pedrl.sim.checks" in imported_modules(path))
    assert not from_sim, f"{from_sim} import pedrl.sim.checks: the checks are in {FLOOR}.checks"
    assert not (PACKAGE / "sim" / "checks.py").exists()
