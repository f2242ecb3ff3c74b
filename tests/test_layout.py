"""The package's import structure: no import cycle between gpsins modules at any depth (imports
inside functions count), and the simulator depends on nothing of the workstation but the shared
formats and the one-line user errors.

The graph is read from the source with ``ast``, nothing is imported: every ``import`` and
``from ... import`` anywhere in a module (top level, functions, ``TYPE_CHECKING`` blocks), relative
imports resolved. ``from pkg import name`` is an edge to ``pkg.name`` when that is a module, else to
``pkg``. Importing a module runs its package's ``__init__`` first, but that is not counted as an edge
here: a package's ``__init__`` is counted only when it is imported by name.
"""

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent / "python"
PACKAGE = "gpsins"

# What gpsins.sim may import from gpsins beyond itself: the formats it shares with the workstation
# (messages, truth file, data set) and the user errors.
# The C++ core is not the workstation: the simulator uses it only to encode subframes.
SIM_ALLOWED = ("gpsins.sim", "gpsins.formats", "gpsins.errors", "gpsins._core")


def module_files() -> dict[str, Path]:
    """Module name -> file, for every module of the package (a package is its ``__init__``)."""
    out = {}
    for path in sorted((ROOT / PACKAGE).rglob("*.py")):
        parts = list(path.relative_to(ROOT).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = path
    return out


def extension_modules() -> set[str]:
    """Compiled modules (the C++ core ``gpsins._core``): nodes without imports of their own."""
    return {".".join(p.relative_to(ROOT).parts[:-1] + (p.name.split(".")[0],)) for p in (ROOT / PACKAGE).rglob("*.so")}


def _resolve(module: str, path: Path, level: int, name: str | None) -> str:
    """The absolute name of a (possibly relative) import in `module` (file `path`)."""
    if level == 0:
        return name or ""
    base = module.split(".")
    if path.name != "__init__.py":
        base = base[:-1]  # a module's package
    if level > 1:
        base = base[: len(base) - (level - 1)]
    return ".".join(base + ([name] if name else []))


def imports_of(module: str, path: Path, modules: set[str]) -> set[str]:
    """The gpsins modules `module` imports anywhere in its source."""
    tree = ast.parse(path.read_text(), filename=str(path))
    found: set[str] = set()

    def add(name: str) -> None:
        # the longest prefix of `name` that is a module of the package
        parts = name.split(".")
        while parts:
            cand = ".".join(parts)
            if cand in modules:
                found.add(cand)
                return
            parts.pop()

    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.split(".")[0] == PACKAGE:
                    add(alias.name)
        elif isinstance(node, ast.ImportFrom):
            target = _resolve(module, path, node.level, node.module)
            if target.split(".")[0] != PACKAGE:
                continue
            for alias in node.names:
                sub = f"{target}.{alias.name}"
                add(sub if sub in modules else target)
    found.discard(module)
    return found


def import_graph() -> dict[str, set[str]]:
    files = module_files()
    names = set(files) | extension_modules() | {f"{PACKAGE}._core"}
    graph = {m: imports_of(m, p, names) for m, p in files.items()}
    return graph | {m: set() for m in names - set(files)}


def strongly_connected(graph: dict[str, set[str]]) -> list[list[str]]:
    """Every strongly connected component of more than one module (Tarjan's algorithm, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    on_stack: set[str] = set()
    stack: list[str] = []
    comps: list[list[str]] = []
    counter = 0
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            node, it = work[-1]
            for nxt in it:
                if nxt not in index:
                    index[nxt] = low[nxt] = counter
                    counter += 1
                    stack.append(nxt)
                    on_stack.add(nxt)
                    work.append((nxt, iter(sorted(graph[nxt]))))
                    break
                if nxt in on_stack:
                    low[node] = min(low[node], index[nxt])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[node])
                if low[node] == index[node]:
                    comp = []
                    while True:
                        w = stack.pop()
                        on_stack.discard(w)
                        comp.append(w)
                        if w == node:
                            break
                    if len(comp) > 1:
                        comps.append(sorted(comp))
    return comps


def find_cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """One shortest cycle through each strongly connected component."""
    return [_one_cycle(graph, set(c)) for c in strongly_connected(graph)]


def _one_cycle(graph: dict[str, set[str]], comp: set[str]) -> list[str]:
    """A shortest cycle through the first module of a strongly connected component (breadth first)."""
    start = min(comp)
    prev: dict[str, str] = {}
    frontier = [start]
    while frontier:
        nxt_frontier = []
        for node in frontier:
            for nxt in sorted(graph[node] & comp):
                if nxt == start:
                    path = [node]
                    while path[-1] != start:
                        path.append(prev[path[-1]])
                    return [start, *reversed(path[:-1]), start] if node != start else [start, start]
                if nxt not in prev:
                    prev[nxt] = node
                    nxt_frontier.append(nxt)
        frontier = nxt_frontier
    return sorted(comp)


def test_graph_is_read():
    graph = import_graph()
    assert "gpsins.cli" in graph and len(graph) > 40
    assert any(graph.values())


def test_no_import_cycle():
    graph = import_graph()
    comps = strongly_connected(graph)
    lines = [" -> ".join(_one_cycle(graph, set(c))) + f"   (modules on cycles: {', '.join(c)})" for c in comps]
    assert not comps, "import cycles:\n" + "\n".join(lines)


def test_sim_depends_only_on_shared_formats():
    bad = []
    for module, deps in sorted(import_graph().items()):
        if module != "gpsins.sim" and not module.startswith("gpsins.sim."):
            continue
        for dep in sorted(deps):
            if not any(dep == a or dep.startswith(a + ".") for a in SIM_ALLOWED):
                bad.append(f"{module} -> {dep}")
    assert not bad, "gpsins.sim imports outside " + ", ".join(SIM_ALLOWED) + ":\n" + "\n".join(bad)


def test_finds_a_cycle():
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}
    assert find_cycles(graph) == [["a", "b", "c", "a"]]


def private_names_used_across_modules(files: dict[str, Path]) -> list[str]:
    """`a.b:_name <- c` for each name with a leading underscore that module c takes from another
    gpsins module a.b, by ``from a.b import _name`` or as an attribute ``b._name`` of the imported
    module: such a name is part of a.b's interface and should say so."""
    names = set(files) | extension_modules() | {f"{PACKAGE}._core"}
    found = set()
    for module, path in files.items():
        tree = ast.parse(path.read_text(), filename=str(path))
        module_aliases: dict[str, str] = {}
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom):
                target = _resolve(module, path, node.level, node.module)
                for alias in node.names:
                    sub = f"{target}.{alias.name}"
                    if sub in names:
                        module_aliases[alias.asname or alias.name] = sub
                    elif _is_private(alias.name) and target in names and target != module:
                        found.add(f"{target}:{alias.name} <- {module}")
            elif isinstance(node, ast.Import):
                for alias in node.names:
                    if alias.name in names:
                        module_aliases[alias.asname or alias.name] = alias.name
        for node in ast.walk(tree):
            if (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name)
                    and node.value.id in module_aliases and _is_private(node.attr)
                    and module_aliases[node.value.id] != module):
                found.add(f"{module_aliases[node.value.id]}:{node.attr} <- {module}")
    return sorted(found)


def _is_private(name: str) -> bool:
    return name.startswith("_") and not name.startswith("__")


def test_no_module_uses_another_modules_private_names():
    found = private_names_used_across_modules(module_files())
    assert not found, "private names used across modules:\n" + "\n".join(found)


def test_finds_a_private_name_used_across_modules(tmp_path):
    pkg = tmp_path / "gpsins"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "sub" / "__init__.py").write_text("")
    (pkg / "sub" / "a.py").write_text("def _hidden():\n    pass\n")
    (pkg / "b.py").write_text("from .sub.a import _hidden\n")
    (pkg / "c.py").write_text("from .sub import a\n\na._hidden()\nfrom . import _core\n")
    files = {"gpsins": pkg / "__init__.py", "gpsins.sub": pkg / "sub" / "__init__.py",
             "gpsins.sub.a": pkg / "sub" / "a.py", "gpsins.b": pkg / "b.py", "gpsins.c": pkg / "c.py"}
    assert private_names_used_across_modules(files) == ["gpsins.sub.a:_hidden <- gpsins.b",
                                                       "gpsins.sub.a:_hidden <- gpsins.c"]


def test_every_expected_failure_names_what_it_raises(request):
    """conftest's rule: an xfail counts only the failure it expects (AssertionError unless it names
    another), so a test stopped by something else (an input now refused) fails instead."""
    marks = [m for item in request.session.items for m in item.iter_markers("xfail")]
    assert all("raises" in m.kwargs for m in marks)
