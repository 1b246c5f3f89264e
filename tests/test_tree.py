"""The shape of the source tree (docs/architecture.md): packages small enough to read, modules
within their size, no circle of imports, no private name borrowed from another module."""

from __future__ import annotations

import ast
from collections import defaultdict
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "src" / "real2sim"
#: Modules a package holds directly, at most (cli/ is one module per verb, and is exempt).
MAX_MODULES = 12
MAX_LINES = 400
EXEMPT_PACKAGES = {"real2sim.cli"}


def module_name(path: Path) -> str:
    parts = ("real2sim",) + path.relative_to(PACKAGE).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


MODULES = {module_name(p): p for p in sorted(PACKAGE.rglob("*.py"))}


def imported(name: str, node: ast.ImportFrom) -> str | None:
    """The absolute module ``node`` (in module ``name``) imports from."""
    if not node.level:
        return node.module
    base = name.split(".")
    if MODULES[name].name != "__init__.py":
        base = base[:-1]
    base = base[: len(base) - node.level + 1]
    return ".".join(base + ([node.module] if node.module else []))


def import_edges() -> tuple[dict[str, set[str]], list[tuple[str, str, str]]]:
    """Every import between real2sim modules (top level, inside functions, under TYPE_CHECKING),
    and the private names imported across modules."""
    edges: dict[str, set[str]] = defaultdict(set)
    privates = []
    for name, path in MODULES.items():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                for alias in node.names:
                    if alias.name in MODULES and alias.name != name:
                        edges[name].add(alias.name)
            elif isinstance(node, ast.ImportFrom):
                source = imported(name, node)
                if not source or not source.startswith("real2sim"):
                    continue
                for alias in node.names:
                    full = f"{source}.{alias.name}"
                    target = full if full in MODULES else source
                    if target in MODULES and target != name:
                        edges[name].add(target)
                    if alias.name.startswith("_") and not alias.name.startswith("__") and full not in MODULES:
                        privates.append((name, source, alias.name))
    return edges, privates


def cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected groups of more than one module (Tarjan's algorithm, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    on_stack: set[str] = set()
    stack: list[str] = []
    found = []
    counter = 0
    for root in MODULES:
        if root in index:
            continue
        work = [(root, iter(sorted(edges.get(root, ()))))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = counter
                    counter += 1
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(edges.get(child, ())))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                group = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    group.append(member)
                    if member == node:
                        break
                if len(group) > 1:
                    found.append(sorted(group))
    return found


def test_no_circle_of_imports():
    """Not at run time, not inside functions, not for type hints: a circle means two modules share
    something that belongs to neither, so a function-local import can never be needed to dodge one."""
    edges, _ = import_edges()
    assert cycles(edges) == []


def test_no_private_name_is_borrowed():
    _, privates = import_edges()
    assert privates == [], "what modules share gets a public name in the module that owns it"


def test_packages_are_small_enough_to_read():
    counts: dict[str, int] = defaultdict(int)
    for name, path in MODULES.items():
        if path.name != "__init__.py":
            counts[name.rsplit(".", 1)[0]] += 1
    crowded = {pkg: n for pkg, n in counts.items() if n > MAX_MODULES and pkg not in EXEMPT_PACKAGES}
    assert crowded == {}, f"split these by concern into sub-packages (at most {MAX_MODULES} modules each)"


@pytest.mark.parametrize("name", sorted(MODULES))
def test_modules_stay_within_their_size(name):
    assert len(MODULES[name].read_text().splitlines()) <= MAX_LINES


def first_line(path: Path) -> str:
    """The first sentence of a module's docstring, on one line (what docs/architecture.md says of it)."""
    doc = ast.get_docstring(ast.parse(path.read_text())) or ""
    text = " ".join(doc.split("\n\n")[0].split())
    cut = text.find(". ")
    return (text[: cut + 1] if 0 < cut < 150 else text[:150]).rstrip()


def tree_listing() -> list[str]:
    """docs/architecture.md's tree: every package and module, indented, each with its first line."""
    lines = []
    for path in sorted(PACKAGE.rglob("*.py"), key=lambda p: p.relative_to(PACKAGE).parts):
        rel = path.relative_to(PACKAGE)
        depth = len(rel.parts) - 1
        if path.name == "__init__.py":
            if depth == 0:
                continue
            lines.append(f"{'  ' * (depth - 1)}{rel.parts[-2]}/  {first_line(path)}")
        else:
            lines.append(f"{'  ' * depth}{path.name}  {first_line(path)}")
    return lines


ARCHITECTURE_PAGE = PACKAGE.parents[1] / "docs" / "architecture.md"


def drawn_tree(text: str) -> list[str]:
    """The tree block of docs/architecture.md, one line per entry."""
    start = text.index("<!-- tree: generated")
    return text[start:text.index("<!-- end of tree -->")].split("```")[1].strip("\n").splitlines()


def write_tree() -> None:
    """Redraw docs/architecture.md's tree from the modules: ``python -m tests.test_tree``."""
    text = ARCHITECTURE_PAGE.read_text()
    old = "\n".join(drawn_tree(text))
    ARCHITECTURE_PAGE.write_text(text.replace(old, "\n".join(tree_listing()), 1))


def test_the_architecture_page_draws_the_tree():
    assert drawn_tree(ARCHITECTURE_PAGE.read_text()) == tree_listing(), "regenerate: python -m tests.test_tree"


if __name__ == "__main__":
    write_tree()
