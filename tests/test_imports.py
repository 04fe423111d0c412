"""The import graph of pedrl (issue 21): no circle, and the users of a learned policy never import a trainer.

Read from the source with ``ast`` (nothing is imported), imports inside functions included: a lazy import that
closes a circle is still a circle. Imports under ``if TYPE_CHECKING:`` (annotations only) never run and are left out.
"""

from pathlib import Path

import pytest

from tests.test_layout import PACKAGE, imported_modules, module_name

TRAINERS = ("pedrl.algos",)
"""The trainers and everything beside them in pedrl/algos (their registry, rollouts, checkpoints to resume)."""
POLICY_USERS = (
    "pedrl.evaluation",
    "pedrl.validation",
    "pedrl.integrations",
    "pedrl.policy_files",
    "pedrl.evaluate",
    "pedrl.validate",
    "pedrl.export",
    "pedrl.rl",
    "pedrl.vq",
    "pedrl.configs",
)
"""What runs a learned policy: they load a :class:`pedrl.rl.TabularPolicy`, never a trainer."""


def graph(root: Path = PACKAGE, *, runtime_only: bool = True) -> dict[str, set[str]]:
    """``module -> modules of pedrl it imports`` (explicit imports; ``from a import b`` counts ``a.b`` when it is a
    module; ``runtime_only=False`` counts the imports under ``if TYPE_CHECKING:`` too). Importing ``a.b.c`` also runs
    the packages ``a`` and ``a.b``: :func:`reachable` adds them."""
    files = {module_name(path, root.parent): path for path in root.rglob("*.py")}
    return {
        name: {
            found
            for found in imported_modules(path, root.parent, runtime_only=runtime_only)
            if found in files and found != name
        }
        for name, path in files.items()
    }


def reachable(edges: dict[str, set[str]], start: str) -> set[str]:
    """Every module whose code runs when ``start`` is imported: its imports, their parent packages, and so on."""
    seen, stack = set(), [start]
    while stack:
        name = stack.pop()
        if name in seen:
            continue
        seen.add(name)
        parts = name.split(".")
        parents = {".".join(parts[:i]) for i in range(1, len(parts))} & set(edges)
        stack.extend(edges.get(name, set()) | parents)
    return seen


def circles(edges: dict[str, set[str]]) -> list[list[str]]:
    """The import circles (strongly connected components of more than one module), Tarjan's algorithm."""
    index, low, on_stack, stack, found, counter = {}, {}, set(), [], [], [0]

    def visit(node: str) -> None:
        index[node] = low[node] = counter[0]
        counter[0] += 1
        stack.append(node)
        on_stack.add(node)
        for nxt in edges[node]:
            if nxt not in index:
                visit(nxt)
                low[node] = min(low[node], low[nxt])
            elif nxt in on_stack:
                low[node] = min(low[node], index[nxt])
        if low[node] == index[node]:
            component = []
            while True:
                top = stack.pop()
                on_stack.discard(top)
                component.append(top)
                if top == node:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for node in sorted(edges):
        if node not in index:
            visit(node)
    return found


def within(name: str, prefixes: tuple[str, ...]) -> bool:
    return any(name == p or name.startswith(f"{p}.") for p in prefixes)


def test_pedrl_has_no_import_circle():
    assert circles(graph()) == []


def test_pedrl_has_no_import_circle_even_through_type_only_imports():
    """A circle of imports under ``if TYPE_CHECKING:`` breaks no run, but it couples the modules all the same."""
    assert circles(graph(runtime_only=False)) == []


@pytest.mark.parametrize("user", POLICY_USERS)
def test_the_users_of_a_policy_never_import_a_trainer(user):
    edges = graph()
    modules = [name for name in edges if within(name, (user,))]
    assert modules, f"{user} is not a module of pedrl"
    for module in modules:
        trainers = sorted(name for name in reachable(edges, module) if within(name, TRAINERS))
        assert not trainers, f"{module} imports {trainers}"


def test_the_checks_see_circles_and_trainers(tmp_path):
    """The controls: a planted circle, and a planted trainer import, are found."""
    package = tmp_path / "pedrl"
    (package / "algos").mkdir(parents=True)
    (package / "__init__.py").write_text("")
    (package / "algos" / "__init__.py").write_text("from pedrl.algos.base import Trainer\n")
    (package / "algos" / "base.py").write_text("def f():\n    from pedrl.policy import load\n")
    (package / "algos" / "typed.py").write_text(
        "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    import pedrl.policy\n"
    )
    (package / "policy.py").write_text("from pedrl.algos import base\n")
    edges = graph(package)
    assert circles(edges) == [["pedrl.algos", "pedrl.algos.base", "pedrl.policy"]]
    assert "pedrl.algos" in reachable(edges, "pedrl.policy")
    assert edges["pedrl.algos.typed"] == set()  # annotations only: it never runs
    assert graph(package, runtime_only=False)["pedrl.algos.typed"] == {"pedrl.policy"}  # but it couples
