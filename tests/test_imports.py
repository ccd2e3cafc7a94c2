"""The package's import graph, read from the source with ``ast``: no import cycle between its
modules (function-level imports included), and no module using another module's private
(underscore) names."""

import ast
from pathlib import Path

import jaxplore

PACKAGE = Path(jaxplore.__file__).resolve().parent


def _modules() -> dict[str, Path]:
  modules = {}
  for path in PACKAGE.rglob("*.py"):
    parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
      parts = parts[:-1]
    modules[".".join(parts)] = path
  return modules


MODULES = _modules()


def _is_private(name: str) -> bool:
  return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def _is_ancestor(package: str, module: str) -> bool:
  """Importing a module's own ancestor package is no dependency: Python initialises it first."""
  return module.startswith(package + ".")


def _scan(name: str, path: Path):
  """(modules ``name`` imports, the other modules' private names it uses) of one module."""
  tree = ast.parse(path.read_text(), filename=str(path))
  is_package = path.name == "__init__.py"
  edges, private, aliases = set(), [], {}

  def target(node: ast.ImportFrom) -> str:
    if not node.level:
      return node.module or ""
    base = name.split(".") if is_package else name.split(".")[:-1]
    base = base[: len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))

  for node in ast.walk(tree):
    if isinstance(node, ast.Import):
      for alias in node.names:
        if alias.name in MODULES:
          edges.add(alias.name)
          if alias.asname:
            aliases[alias.asname] = alias.name
    elif isinstance(node, ast.ImportFrom):
      module = target(node)
      if module not in MODULES:
        continue
      for alias in node.names:
        full = f"{module}.{alias.name}"
        if full in MODULES:  # a submodule
          edges.add(full)
          aliases[alias.asname or alias.name] = full
        else:
          edges.add(module)
          if _is_private(alias.name) and module != name:
            private.append(f"{name} imports {full}")
  for node in ast.walk(tree):
    if (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name)
        and node.value.id in aliases and _is_private(node.attr) and aliases[node.value.id] != name):
      private.append(f"{name} uses {aliases[node.value.id]}.{node.attr}")
  edges = {e for e in edges if e != name and not _is_ancestor(e, name)}
  return edges, private


GRAPH = {name: _scan(name, path) for name, path in MODULES.items()}


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
  """The strongly connected components with more than one module (Tarjan)."""
  index, low, stack, on_stack, found = {}, {}, [], set(), []

  def visit(v):
    index[v] = low[v] = len(index)
    stack.append(v)
    on_stack.add(v)
    for w in graph[v]:
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


def test_the_scan_sees_the_package():
  # The graph is not vacuous: the host layer's known edges are there.
  assert {"jaxplore.runner", "jaxplore.sweeps", "jaxplore.resolve",
          "jaxplore.sweeps.schedule"} <= set(GRAPH)
  assert "jaxplore.resolve" in GRAPH["jaxplore.runner"][0]
  assert "jaxplore.driver" in GRAPH["jaxplore.sweeps.execute"][0]
  assert "jaxplore.sweeps" in GRAPH["jaxplore.runner"][0]  # a function-level import counts


def test_the_checks_catch_what_they_look_for():
  assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
  assert _cycles({"a": {"b"}, "b": set()}) == []
  assert _is_private("_resolve_group") and not _is_private("__version__")


def test_no_import_cycle():
  assert _cycles({name: edges for name, (edges, _) in GRAPH.items()}) == []


def test_no_module_uses_another_modules_private_names():
  assert [use for _, (_, private) in sorted(GRAPH.items()) for use in private] == []
