"""The kernels read their packed inputs by name: no field of a named tuple that a kernel takes (the room's
constants, the state, the walls, the scratch ...) is read by position, ``room.steering[0]``, in any module that
declares a kernel. A field that is an array indexed by agent, cell or coordinate is read as ever
(``state.positions[r, i, 0]``); what is refused is a field that packs several values read by a literal first index."""

import ast
from pathlib import Path

from pedrl.sim.params import KernelRoom

PACKAGE = Path(__file__).resolve().parents[1] / "pedrl"
INTERNAL = {"Cells"}
"""Named tuples the kernels build for themselves (the grid of cells: its origin and cell size ``box``), no input."""


def _packed_fields() -> dict[str, str]:
    """Every field of every named tuple declared in the package (``class X(NamedTuple)``) and of ``KernelRoom``, with
    the class that declares it."""
    fields = {name: "KernelRoom" for name in KernelRoom._fields}
    for path in PACKAGE.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            bases = [ast.unparse(base) for base in getattr(node, "bases", [])]
            if isinstance(node, ast.ClassDef) and "NamedTuple" in bases and node.name not in INTERNAL:
                for item in node.body:
                    if isinstance(item, ast.AnnAssign) and isinstance(item.target, ast.Name):
                        fields.setdefault(item.target.id, node.name)
    return fields


def positional_reads(source: str, fields: dict[str, str]) -> list[str]:
    """``x.field[<literal>...]`` reads of a packed field whose first index is an integer literal. (A kernel that
    takes the field under its own name, ``cuts[1]``, is not followed: the k-d tree's and the literal search's scratch
    rows are read so.)"""
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Subscript) and isinstance(node.value, ast.Attribute) and node.value.attr in fields:
            index = node.slice.elts[0] if isinstance(node.slice, ast.Tuple) else node.slice
            if isinstance(index, ast.Constant) and type(index.value) is int:
                found.append(f"line {node.lineno}: {ast.unparse(node)} ({fields[node.value.attr]})")
    return found


def test_the_reader_finds_a_positional_read_of_a_packed_field():
    fields = {"steering": "KernelRoom", "totals": "Trace"}
    source = "a = room.steering[1]\nb = trace.totals[0, r, i]\nc = state.steering[i]\nd = room.other[0]\n"
    assert positional_reads(source, fields) == [
        "line 1: room.steering[1] (KernelRoom)",
        "line 2: trace.totals[0, r, i] (Trace)",
    ]


def test_no_kernel_module_reads_a_packed_input_by_position():
    fields = _packed_fields()
    assert {"grid_min_agents", "neighbour_range", "returns", "acted_moved", "sizes"} <= set(fields)
    found = []
    for path in sorted(PACKAGE.rglob("*.py")):
        source = path.read_text()
        if "cached_njit" in source and path.parent.name != "bench":  # the benches' host code reads host objects
            found += [f"{path.relative_to(PACKAGE.parent)} {read}" for read in positional_reads(source, fields)]
    assert not found, "read by position, not by name:\n" + "\n".join(found)
