"""The modules of labrunner/ form layers: no import cycle, and no module imports another's private name.

Read with ``ast`` from the sources (nothing is imported). What counts (docs/architecture.md,
"Layers"):

- every ``import`` / ``from … import`` of a labrunner module, at module level *or inside a
  function*: a function-local import defers the cost of loading a module, not the dependency, so a
  lazy import that closes a circle is a circle;
- not the imports under ``if TYPE_CHECKING:`` (they never run), nor the implicit import of a parent
  package, nor registries that name a module as a string (``control.factory.REGISTRY``, rig kinds'
  entry points): those are plug-in points, read at run time;
- a private name is ``_name`` (not ``__dunder__``) of another module, taken by ``from m import _name``
  or read as ``m._name`` through an imported module. A private *module* (``labrunner._ufunc``) is
  the package's own and may be imported inside labrunner.
"""

from __future__ import annotations

import ast
from dataclasses import dataclass
from pathlib import Path

PACKAGE = Path(__file__).resolve().parent.parent / "labrunner"


@dataclass(frozen=True)
class Edge:
    source: str
    target: str
    line: int
    name: str | None  # the name taken from the target, if not a module


def _private(name: str) -> bool:
    return name.startswith("_") and not name.startswith("__")


def _modules(root: Path) -> dict[str, Path]:
    out = {}
    for path in sorted(root.rglob("*.py")):
        parts = path.relative_to(root.parent).with_suffix("").parts
        out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return out


def _type_checking_nodes(tree: ast.AST) -> set[int]:
    hidden: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            hidden.update(id(n) for stmt in node.body for n in ast.walk(stmt))
    return hidden


def _owner(name: str, modules: dict[str, Path]) -> str | None:
    while name not in modules and "." in name:
        name = name.rsplit(".", 1)[0]
    return name if name in modules else None


def import_edges(root: Path) -> tuple[dict[str, Path], list[Edge], list[str]]:
    """(modules, import edges between them, private names read through imported modules)."""
    modules = _modules(root)
    top = root.name
    edges: list[Edge] = []
    attribute_reads: list[str] = []
    for module, path in modules.items():
        tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
        package = module if path.name == "__init__.py" else module.rpartition(".")[0]
        hidden = _type_checking_nodes(tree)
        aliases: dict[str, str] = {}  # local name → imported labrunner module
        for node in ast.walk(tree):
            if id(node) in hidden:
                continue
            if isinstance(node, ast.Import):
                for alias in node.names:
                    if alias.name.split(".")[0] == top and (target := _owner(alias.name, modules)):
                        edges.append(Edge(module, target, node.lineno, None))
                        if alias.asname:
                            aliases[alias.asname] = target
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    parts = package.split(".")[: len(package.split(".")) - node.level + 1]
                    base = ".".join(parts + ([node.module] if node.module else []))
                if base.split(".")[0] != top:
                    continue
                for alias in node.names:
                    if f"{base}.{alias.name}" in modules:
                        edges.append(Edge(module, f"{base}.{alias.name}", node.lineno, None))
                        aliases[alias.asname or alias.name] = f"{base}.{alias.name}"
                    elif target := _owner(base, modules):
                        edges.append(Edge(module, target, node.lineno, alias.name))
        for node in ast.walk(tree):
            if (
                isinstance(node, ast.Attribute)
                and isinstance(node.value, ast.Name)
                and node.value.id in aliases
                and aliases[node.value.id] != module
                and _private(node.attr)
            ):
                attribute_reads.append(f"{module}:{node.lineno} reads {aliases[node.value.id]}.{node.attr}")
    return modules, edges, attribute_reads


def cycles(edges: list[Edge]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan), each sorted."""
    graph: dict[str, set[str]] = {}
    for e in edges:
        if e.source != e.target:
            graph.setdefault(e.source, set()).add(e.target)
            graph.setdefault(e.target, set())
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def private_imports(edges: list[Edge]) -> list[str]:
    return [
        f"{e.source}:{e.line} imports {e.target}.{e.name}"
        for e in edges
        if e.name and _private(e.name) and e.source != e.target
    ]


def _describe(component: list[str], edges: list[Edge]) -> str:
    inside = set(component)
    return "; ".join(f"{e.source}:{e.line} → {e.target}" for e in edges if e.source in inside and e.target in inside)


def test_labrunner_has_no_import_cycle():
    _, edges, _ = import_edges(PACKAGE)
    found = cycles(edges)
    assert not found, "import cycles (function-local imports count): " + " | ".join(_describe(c, edges) for c in found)


def test_no_module_imports_a_private_name_of_another():
    _, edges, reads = import_edges(PACKAGE)
    assert private_imports(edges) + reads == []


def test_the_guided_layer_sits_above_the_plain_runner():
    # the layers of docs/architecture.md: procedures propose (pure), spec parses and plans, the
    # scheduler executes points, guided_run drives rounds over it, runner holds the operations
    _, edges, _ = import_edges(PACKAGE)
    deps: dict[str, set[str]] = {}
    for e in edges:
        deps.setdefault(e.source, set()).add(e.target)
    c = "labrunner.campaign."
    for procedure in ("guided", "guided_walks", "guided_refine"):
        assert not {d for d in deps.get(c + procedure, ()) if d.startswith(c)} - {
            c + "grid",
            c + "expressions",
            c + "guided",
        }
    assert c + "guided_run" not in deps[c + "spec"] | deps[c + "scheduler"] | deps.get(c + "worker", set())
    assert c + "runner" not in deps[c + "guided_run"]


def _package(tmp_path: Path, files: dict[str, str]) -> Path:
    root = tmp_path / "labrunner"
    for name, text in files.items():
        path = root / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    return root


def test_the_checker_finds_a_cycle_closed_by_a_function_local_import(tmp_path):
    root = _package(
        tmp_path,
        {
            "__init__.py": "",
            "a.py": "from labrunner import b\n",
            "b.py": "def f():\n    from labrunner.c import g\n",
            "c.py": "from . import a\nfrom typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from labrunner import d\n",
            "d.py": "import labrunner.c\n",
        },
    )
    _, edges, _ = import_edges(root)
    assert cycles(edges) == [["labrunner.a", "labrunner.b", "labrunner.c"]]  # d → c only under TYPE_CHECKING


def test_the_checker_finds_private_names_taken_or_read(tmp_path):
    root = _package(
        tmp_path,
        {
            "__init__.py": "",
            "_util.py": "def clip(): ...\n",
            "a.py": "def _x(): ...\ndef __dunder__(): ...\n",
            "b.py": "from labrunner._util import clip\nfrom labrunner.a import _x, __dunder__\n",
            "c.py": "from labrunner import a as m\nm._x()\n",
        },
    )
    _, edges, reads = import_edges(root)
    assert private_imports(edges) == ["labrunner.b:2 imports labrunner.a._x"]
    assert reads == ["labrunner.c:2 reads labrunner.a._x"]
