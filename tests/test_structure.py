"""The package's structure (#26), read from its source with ``ast``: no import cycle among sss_jax's modules
(function-local imports count), and technique names compared in few places outside cli/ and engines/."""

import ast
import pathlib

import sss_jax as sj

PACKAGE = pathlib.Path(sj.__file__).resolve().parent


def _module_name(path: pathlib.Path) -> str:
    parts = ("sss_jax",) + path.relative_to(PACKAGE).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _modules() -> dict[str, pathlib.Path]:
    return {_module_name(p): p for p in sorted(PACKAGE.rglob("*.py"))}


def _resolve(name: str, modules) -> str | None:
    """The sss_jax module ``name`` is (or, for ``from pkg import mod``, the closest enclosing module that exists)."""
    while name and name not in modules:
        name = name.rpartition(".")[0]
    return name or None


def import_graph() -> dict[str, set[str]]:
    """module -> the sss_jax modules it imports anywhere in its body (top level, functions, classes). A package's
    ``__init__`` counts as imported by ``from .pkg import x`` only where ``x`` is not itself a submodule."""
    modules = _modules()
    graph = {}
    for name, path in modules.items():
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        edges = set()
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    base = package
                    for _ in range(node.level - 1):
                        base = base.rpartition(".")[0]
                    base = f"{base}.{node.module}" if node.module else base
                else:
                    base = node.module or ""
                # ``from .pkg import sub``: the submodule; ``from .mod import f``: the module
                targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in modules else base for a in node.names]
            else:
                continue
            for target in targets:
                if target.startswith("sss_jax"):
                    resolved = _resolve(target, modules)
                    if resolved and resolved != name:
                        edges.add(resolved)
        graph[name] = edges
    return graph


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One cycle of ``graph`` as a list of modules (first == last), or None (depth-first search, three colours)."""
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(node):
        state[node] = 1
        stack.append(node)
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == 1:
                return stack[stack.index(nxt):] + [nxt]
            if nxt not in state:
                found = visit(nxt)
                if found:
                    return found
        stack.pop()
        state[node] = 2
        return None

    for node in sorted(graph):
        if node not in state:
            found = visit(node)
            if found:
                return found
    return None


def test_the_cycle_finder_finds_a_cycle():
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": set()}) is None


def test_the_graph_sees_function_local_imports():
    graph = import_graph()
    # the CLI imports its work inside each command's function (to start fast): those edges must be in the graph
    assert "sss_jax._batch" in graph["sss_jax.cli._apply"] or any(
        m.startswith("sss_jax._") for m in graph["sss_jax.cli._apply"])
    assert "sss_jax._techniques._burley" in graph["sss_jax._techniques._burley_technique"]


def test_no_import_cycle():
    cycle = find_cycle(import_graph())
    assert cycle is None, "import cycle: " + " -> ".join(cycle)
