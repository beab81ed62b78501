"""The package's layout, checked on its source: imports point one way and stay public (issue 22).

Every ``.py`` file of ``symmon/`` is parsed (nothing is imported) and all its imports are
read, those inside functions and those under ``if TYPE_CHECKING:`` included: an import for
annotations only is still a dependency, and leaving it out hid the cycle of
``symmon.filters`` (issue 38: ``nonlinear`` imported ``export``, ``fit`` and ``strategy``,
which imported it back for their annotations and reached into it at run time). An import of a package is an import of its ``__init__.py``:
``from ..transforms import Transform`` imports ``symmon.transforms``, while
``from ..compile import ccache`` imports the module ``symmon.compile.ccache``. A call
``importlib.import_module("symmon.x")`` with a constant name counts as an import; one with a
computed name (the CLI's ``reproduce`` picks a figure module by name) cannot be followed.

A *unit* is a subpackage (``symmon.core``, with all its modules) or one of the flat modules
at the top of the package (``symmon.errors``), each a unit of its own. The rules, one test each:

- no import cycle between modules;
- no private name (a module or a name starting with one underscore) used across units;
- every import points to the importer's own layer or a lower one (:data:`LAYERS`); the
  package's face, ``symmon/__init__.py``, re-exports everything and may import anything;
- at most :data:`MAX_TOP_MODULES` flat modules at the top of the package;
- no module-level ``__getattr__`` (no back-compatibility shims that alias old names);
- the tests use no private name of the package outside their own folder's subpackage:
  ``tests/units/`` may test ``symmon.units.lemmas._reduce``, ``tests/core/`` may not, and
  the tests at the top of ``tests/`` use public names only;
- test modules have unique file names (pytest imports them by name, without packages).

A *private use* is a ``from m import _x`` or ``import m._x``, an attribute ``m._x`` of a name
bound to the package by an import, or ``setattr`` / ``getattr`` / ``delattr`` /
``monkeypatch.setattr`` with such a target and the name ``"_x"`` (or a dotted string
``"symmon.m._x"``). Names of the form ``_x_`` (IPython's ``_repr_latex_``) are protocols, not
private. The bindings are collected over the whole file, whatever the scope.

``python tests/test_layout.py`` prints the measures of the layout (modules at the top,
cycles, private imports, the longest chain of imports).
"""

from __future__ import annotations

import ast
import sys
from collections import Counter
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Iterable, Iterator

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = "symmon"
SOURCE = ROOT / PACKAGE
TESTS = ROOT / "tests"

#: The units from the bottom layer up. A module may import from its own layer and the
#: layers below; a new subpackage or flat module is placed here before it can pass.
LAYERS: tuple[tuple[str, ...], ...] = (
    ("symmon.errors", "symmon.io", "symmon.progress", "symmon.latex", "symmon.derive", "symmon.version",
     "symmon.timelimit"),
    ("symmon.core",),
    ("symmon.compile",),
    ("symmon.transforms",),
    ("symmon.propagation", "symmon.codegen"),
    ("symmon.measures", "symmon.estimation"),
    ("symmon.units", "symmon.filters", "symmon.verify"),
    ("symmon.files",),
    ("symmon.cli", "symmon.reproduce", "symmon.testing"),
)
#: symmon/__init__.py: the one public face, above every layer.
FACE = PACKAGE
#: Flat modules at the top of the package (symmon/*.py besides __init__.py).
MAX_TOP_MODULES = 14

#: Private uses the test rule lets through, each with its reason.
ALLOWED_PRIVATE_IN_TESTS: dict[tuple[str, str], str] = {}

#: Calls that read or write an attribute named by a string: f(target, "name", ...).
_ATTRIBUTE_CALLS = {"setattr", "getattr", "delattr", "hasattr"}


# --------------------------------------------------------------------------- reading the source
@dataclass(frozen=True)
class Module:
    """A module of the package: its dotted name and file (``__init__.py`` for a package)."""

    name: str
    path: Path
    is_package: bool


@dataclass(frozen=True)
class Import:
    """One import: ``importer`` (a module, or a test file) imports the module ``target``;
    ``name`` is what a ``from`` import takes from it when that is not a module itself."""

    importer: str
    target: str
    name: str | None
    line: int


@dataclass(frozen=True)
class PrivateUse:
    """A private name ``name`` of the package's module ``module``, used at ``where``."""

    module: str
    name: str
    where: str
    line: int

    @property
    def full(self) -> str:
        return f"{self.module}.{self.name}"


@lru_cache(maxsize=None)
def package_modules() -> dict[str, Module]:
    """Every module of the package by dotted name (``symmon.core`` is core/__init__.py)."""
    mods = {}
    for path in sorted(SOURCE.rglob("*.py")):
        parts = list(path.relative_to(ROOT).with_suffix("").parts)
        is_package = parts[-1] == "__init__"
        if is_package:
            parts.pop()
        mods[".".join(parts)] = Module(".".join(parts), path, is_package)
    return mods


@lru_cache(maxsize=None)
def _tree(path: Path) -> ast.Module:
    return ast.parse(path.read_text(encoding="utf-8"), filename=str(path))


def _nodes(node: ast.AST) -> Iterator[ast.AST]:
    """All nodes below ``node``, the bodies of ``if TYPE_CHECKING:`` blocks included."""
    return ast.walk(node)


def _deepest_module(dotted: str) -> str:
    """The longest prefix of ``dotted`` that is a module of the package."""
    mods = package_modules()
    while dotted not in mods and "." in dotted:
        dotted = dotted.rsplit(".", 1)[0]
    return dotted


def _in_package(dotted: str | None) -> bool:
    return bool(dotted) and (dotted == PACKAGE or dotted.startswith(PACKAGE + "."))


def _called(node: ast.Call) -> str | None:
    """The name of the function a call calls: ``f`` of ``f(...)`` and of ``a.b.f(...)``."""
    func = node.func
    return func.attr if isinstance(func, ast.Attribute) else func.id if isinstance(func, ast.Name) else None


def _import_module_name(node: ast.AST) -> str | None:
    """``m`` of a call ``importlib.import_module("m")`` (or ``import_module("m")``)."""
    if (isinstance(node, ast.Call) and _called(node) == "import_module" and node.args
            and isinstance(node.args[0], ast.Constant) and isinstance(node.args[0].value, str)):
        return node.args[0].value
    return None


def _from_source(node: ast.ImportFrom, importer: Module | None) -> str | None:
    """The module a ``from`` import reads from, its relative dots resolved."""
    if not node.level:
        return node.module
    if importer is None:  # a relative import outside the package (a test file)
        return None
    base = importer.name.split(".")
    if not importer.is_package:
        base.pop()
    base = base[: len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def imports_of(tree: ast.Module, importer: str, module: Module | None = None) -> list[Import]:
    """The imports of the package's modules in ``tree`` (a module of it, or a test file)."""
    mods = package_modules()
    found = []
    for node in _nodes(tree):
        if isinstance(node, ast.Import):
            found += [Import(importer, _deepest_module(a.name), None, node.lineno)
                      for a in node.names if _in_package(a.name)]
        elif isinstance(node, ast.ImportFrom):
            source = _from_source(node, module)
            if not _in_package(source):
                continue
            for alias in node.names:
                sub = f"{source}.{alias.name}"
                if sub in mods:
                    found.append(Import(importer, sub, None, node.lineno))
                else:
                    found.append(Import(importer, _deepest_module(source), alias.name, node.lineno))
        elif _in_package(name := _import_module_name(node)):
            found.append(Import(importer, _deepest_module(name), None, node.lineno))
    return found


def _is_private(name: str) -> bool:
    """``_x``: private. ``__x__`` (dunder) and ``_x_`` (a protocol such as _repr_latex_) are not."""
    return name.startswith("_") and not name.startswith("__") and not (len(name) > 2 and name.endswith("_"))


def _private_part(dotted: str) -> int | None:
    """The index of the first private component of a dotted name below the package, if any."""
    for i, part in enumerate(dotted.split(".")[1:], start=1):
        if _is_private(part):
            return i
    return None


def _private_in_dotted(dotted: str, where: str, line: int) -> PrivateUse | None:
    """``symmon.a._b.c`` → the private ``_b`` of ``symmon.a``."""
    i = _private_part(dotted)
    if i is None:
        return None
    parts = dotted.split(".")
    return PrivateUse(_deepest_module(".".join(parts[:i])), parts[i], where, line)


def _bindings(tree: ast.Module, module: Module | None) -> dict[str, str]:
    """Names bound to the package by imports: name → the dotted module or object it stands for."""
    bound = {}
    for node in _nodes(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                if _in_package(a.name):
                    bound[a.asname or a.name.split(".")[0]] = a.name if a.asname else a.name.split(".")[0]
        elif isinstance(node, ast.ImportFrom):
            source = _from_source(node, module)
            if _in_package(source):
                for a in node.names:
                    if a.name != "*":
                        bound[a.asname or a.name] = f"{source}.{a.name}"
        elif (isinstance(node, ast.Assign) and len(node.targets) == 1 and isinstance(node.targets[0], ast.Name)
              and _in_package(name := _import_module_name(node.value))):
            bound[node.targets[0].id] = name
    return bound


def _dotted(node: ast.AST, bound: dict[str, str]) -> str | None:
    """The dotted name an expression ``a.b.c`` stands for when ``a`` is bound to the package."""
    if isinstance(node, ast.Name):
        return bound.get(node.id)
    if isinstance(node, ast.Attribute):
        base = _dotted(node.value, bound)
        return None if base is None else f"{base}.{node.attr}"
    return None


def private_uses(tree: ast.Module, where: str, module: Module | None = None) -> list[PrivateUse]:
    """The private names of the package that ``tree`` imports or reaches (see the module doc)."""
    imports = imports_of(tree, where, module)
    uses = []
    for imp in imports:
        if (use := _private_in_dotted(imp.target, where, imp.line)) is not None:
            uses.append(use)
        elif imp.name is not None and _is_private(imp.name):
            uses.append(PrivateUse(imp.target, imp.name, where, imp.line))
    bound = _bindings(tree, module)
    for node in _nodes(tree):
        if isinstance(node, ast.Attribute) and _is_private(node.attr):
            base = _dotted(node.value, bound)
            if base is not None:
                uses.append(PrivateUse(_deepest_module(base), node.attr, where, node.lineno))
        elif isinstance(node, ast.Call) and node.args and _called(node) in _ATTRIBUTE_CALLS:
            first = node.args[0]
            if isinstance(first, ast.Constant) and isinstance(first.value, str) and _in_package(first.value):
                if (use := _private_in_dotted(first.value, where, node.lineno)) is not None:
                    uses.append(use)  # monkeypatch.setattr("symmon.m._x", value)
            elif len(node.args) >= 2 and isinstance(node.args[1], ast.Constant):
                name, base = node.args[1].value, _dotted(first, bound)
                if base is not None and isinstance(name, str) and _is_private(name):
                    uses.append(PrivateUse(_deepest_module(base), name, where, node.lineno))
    # the same name twice on one line is one use
    return sorted(set(uses), key=lambda u: (u.line, u.full))


# --------------------------------------------------------------------------- the import graph
def unit(module: str) -> str:
    """The subpackage a module belongs to, or the flat module itself (``symmon`` for the face)."""
    return ".".join(module.split(".")[:2])


def layer(unit_name: str) -> int | None:
    """The layer of a unit (0 at the bottom); the face is above all; ``None``: not placed."""
    if unit_name == FACE:
        return len(LAYERS)
    for i, units in enumerate(LAYERS):
        if unit_name in units:
            return i
    return None


@lru_cache(maxsize=None)
def package_imports() -> tuple[Import, ...]:
    """Every import of one module of the package by another."""
    found = []
    for name, mod in package_modules().items():
        found += [i for i in imports_of(_tree(mod.path), name, mod) if i.target != name]
    return tuple(found)


@lru_cache(maxsize=None)
def graph() -> dict[str, frozenset[str]]:
    """Module → the modules it imports."""
    edges: dict[str, set[str]] = {m: set() for m in package_modules()}
    for imp in package_imports():
        edges[imp.importer].add(imp.target)
    return {m: frozenset(t) for m, t in edges.items()}


def strongly_connected(edges: dict[str, frozenset[str]]) -> list[list[str]]:
    """The strongly connected components (Tarjan), each sorted; a cycle is one of size > 1."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    components: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(edges[v]):
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
            components.append(sorted(component))

    limit = sys.getrecursionlimit()
    sys.setrecursionlimit(max(limit, 10 * len(edges) + 100))
    try:
        for v in sorted(edges):
            if v not in index:
                visit(v)
    finally:
        sys.setrecursionlimit(limit)
    return components


def cycles(edges: dict[str, frozenset[str]]) -> list[list[str]]:
    """The modules of each import cycle."""
    return [c for c in strongly_connected(edges) if len(c) > 1]


def a_cycle(component: list[str], edges: dict[str, frozenset[str]]) -> list[str]:
    """One closed path through a strongly connected component: [a, b, ..., a]."""
    members = set(component)
    start = component[0]
    path, seen = [start], {start}

    def extend(v: str) -> bool:
        for w in sorted(edges[v] & members):
            if w == start:
                path.append(w)
                return True
            if w not in seen:
                seen.add(w)
                path.append(w)
                if extend(w):
                    return True
                path.pop()
        return False

    extend(start)
    return path


def longest_chain(edges: dict[str, frozenset[str]], exclude: Iterable[str] = ()) -> list[str]:
    """The longest chain of imports a → b → ..., each cycle collapsed into one step (its
    modules joined by ``+``), not starting at the modules in ``exclude``."""
    components = strongly_connected(edges)
    of = {m: i for i, c in enumerate(components) for m in c}
    down: dict[int, set[int]] = {i: set() for i in range(len(components))}
    for v, ws in edges.items():
        down[of[v]].update(of[w] for w in ws if of[w] != of[v])
    best: dict[int, list[int]] = {}
    # Tarjan lists a component after every component it reaches: one pass bottom up.
    for i in range(len(components)):
        below = [best[j] for j in down[i]]
        best[i] = [i] + max(below, key=len, default=[])
    starts = [i for i in range(len(components)) if not set(components[i]) & set(exclude)]
    chain = max((best[i] for i in starts), key=len, default=[])
    return ["+".join(components[i]) for i in chain]


def suite_files() -> list[Path]:
    """The Python files of the test suite."""
    return sorted(TESTS.rglob("*.py"))


def folder_unit(path: Path) -> str | None:
    """The subpackage whose private names a test file may use: its folder's namesake."""
    parts = path.relative_to(TESTS).parts
    if len(parts) < 2:
        return None
    candidate = f"{PACKAGE}.{parts[0]}"
    return candidate if candidate in package_modules() and package_modules()[candidate].is_package else None


def _rel(path: Path) -> str:
    return path.relative_to(ROOT).as_posix()


# --------------------------------------------------------------------------- the rules
def test_no_import_cycles():
    edges = graph()
    found = cycles(edges)
    assert not found, "import cycles (each: its modules, then one path through them):\n" + "\n".join(
        f"  {', '.join(c)}\n    {' -> '.join(a_cycle(c, edges))}" for c in found)


def test_an_import_for_annotations_only_counts():
    """An import under ``if TYPE_CHECKING:`` is a dependency too (issue 38): skipping it hid
    the cycle of symmon.filters, whose fit, export and strategies imported the filter back."""
    mod = package_modules()["symmon.filters.gaussian.fit"]
    tree = ast.parse("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n"
                     "    from .nonlinear import NonlinearKalmanFilter\n")
    assert [(i.target, i.name) for i in imports_of(tree, mod.name, mod)] == [
        ("symmon.filters.gaussian.nonlinear", "NonlinearKalmanFilter")]


def test_no_private_names_across_subpackages():
    mods = package_modules()
    bad = [use for name, mod in mods.items() for use in private_uses(_tree(mod.path), name, mod)
           if unit(use.where) != unit(use.module)]
    assert not bad, "private names used across units (subpackages or flat modules):\n" + "\n".join(
        f"  {u.where} (line {u.line}) uses {u.full}" for u in bad)


#: The family rooms of symmon.filters: each is a unit of its own for private names (no family
#: reaches into another's internals, nor the floor into a family's), below the subpackage's.
FAMILIES = ("symmon.filters.gaussian", "symmon.filters.particle", "symmon.filters.mixture", "symmon.filters.ensemble")


def room(module: str) -> str:
    """A module's family room of symmon.filters, else its unit."""
    return next((f for f in FAMILIES if module == f or module.startswith(f + ".")), unit(module))


def test_no_private_names_across_filter_families():
    mods = package_modules()
    bad = [use for name, mod in mods.items() if name.startswith("symmon.filters")
           for use in private_uses(_tree(mod.path), name, mod)
           if room(use.where) != room(use.module) and use.module.startswith("symmon.filters")]
    assert not bad, "private names used across the filter families (or by the floor from a family):\n" + "\n".join(
        f"  {u.where} (line {u.line}) uses {u.full}" for u in bad)


def test_no_import_goes_through_a_subpackages_init():
    """A name is imported from the module that defines it: an import through a subpackage's
    ``__init__`` imports every module it gathers (docs/architecture.md)."""
    mods = package_modules()
    bad = []
    for imp in package_imports():
        target = mods.get(imp.target)
        if imp.importer == FACE or target is None or not target.is_package or imp.name is None:
            continue
        if imp.target == imp.importer or imp.importer.startswith(imp.target + ".") and mods[imp.importer].is_package:
            continue  # a subpackage's __init__ gathering its own modules
        bad.append(f"  {imp.importer} (line {imp.line}) imports {imp.name} through {imp.target}")
    assert not bad, "imports through a subpackage's __init__:\n" + "\n".join(sorted(set(bad)))


ARCHITECTURE = ROOT / "docs" / "architecture.md"


def documented_modules() -> set[str]:
    """The modules the layer table of docs/architecture.md lists: each row's home
    (``symmon/filters/gaussian/``, or flat modules ``symmon/errors.py``) with its modules."""
    import re

    found = set()
    for line in ARCHITECTURE.read_text(encoding="utf-8").splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) < 4 or not cells[1].startswith("`symmon"):
            continue
        for home in re.findall(r"`([\w/.]+)`", cells[1]):
            if home.endswith("/"):  # a subpackage: its modules are the next cell's
                found |= {home.replace("/", ".") + m for m in re.findall(r"`(\w+)`", cells[2])}
            elif home.endswith(".py") and not home.endswith("__init__.py"):  # flat modules of the top
                found.add("symmon." + home.removeprefix("symmon/").removesuffix(".py"))
    return found


def test_the_architecture_table_lists_every_module():
    """docs/architecture.md's table tells the truth: every module of the package is in it, and
    nothing it lists is gone (issue 49)."""
    modules = {m for m, mod in package_modules().items() if not mod.is_package and m != FACE}
    listed = documented_modules()
    missing, stale = sorted(modules - listed), sorted(listed - modules)
    assert not missing and not stale, (f"modules missing from the table of docs/architecture.md: {missing}; "
                                       f"listed but not in the package: {stale}")


def test_the_stated_longest_chain_is_the_measured_one():
    """The chain docs/architecture.md states is the longest chain of imports, as measured."""
    import re

    text = ARCHITECTURE.read_text(encoding="utf-8")
    stated = re.search(r"The longest chain of imports.*?:\n(.*?), (\d+) modules", text, re.S)
    assert stated, "docs/architecture.md states no longest chain ('The longest chain of imports … N modules')"
    edges = graph()
    chain = longest_chain(edges, exclude=[FACE])
    names = [s.strip().strip("`") for s in re.split(r"→", stated.group(1).replace("\n", " "))]
    names = ["symmon." + n if not n.startswith("symmon") else n for n in names]
    # Several chains may be longest: the stated one must be one of them, a path of real imports.
    assert int(stated.group(2)) == len(chain) == len(names)
    missing = [f"{a} → {b}" for a, b in zip(names, names[1:]) if b not in edges.get(a, ())]
    assert not missing, f"the stated chain has steps that are no imports: {missing}"


def test_every_unit_has_a_layer():
    units = sorted({unit(m) for m in package_modules()} - {FACE})
    missing = [u for u in units if layer(u) is None]
    assert not missing, f"units not placed in LAYERS of {_rel(Path(__file__))}: {', '.join(missing)}"
    listed = [u for units_ in LAYERS for u in units_]
    stale = sorted(set(listed) - set(units))
    assert not stale, f"LAYERS names units that do not exist: {', '.join(stale)}"
    assert len(listed) == len(set(listed)), f"a unit is in two layers: {Counter(listed).most_common(1)}"


def test_imports_point_down_the_layers():
    bad = []
    for imp in package_imports():
        here, there = layer(unit(imp.importer)), layer(unit(imp.target))
        if imp.importer != FACE and here is not None and there is not None and there > here:
            bad.append(f"  {imp.importer} (layer {here}, line {imp.line}) imports {imp.target} (layer {there})")
    assert not bad, "imports that point up the layers:\n" + "\n".join(sorted(set(bad)))


def test_at_most_14_modules_at_the_top():
    top = top_modules()
    assert len(top) <= MAX_TOP_MODULES, (
        f"{len(top)} flat modules at the top of {PACKAGE}/ (at most {MAX_TOP_MODULES}): {', '.join(top)}")


def test_no_module_level_getattr():
    bad = []
    for name, mod in package_modules().items():
        for node in _tree(mod.path).body:
            defines = (isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and node.name == "__getattr__") or (
                isinstance(node, (ast.Assign, ast.AnnAssign)) and any(
                    isinstance(t, ast.Name) and t.id == "__getattr__"
                    for t in (node.targets if isinstance(node, ast.Assign) else [node.target])))
            if defines:
                bad.append(f"  {name} (line {node.lineno})")
    assert not bad, "module-level __getattr__ (a back-compatibility shim):\n" + "\n".join(bad)


def test_tests_use_no_private_names_of_other_subpackages():
    bad = []
    for path in suite_files():
        own = folder_unit(path)
        for use in private_uses(_tree(path), _rel(path)):
            if own is not None and unit(use.module) == own:
                continue
            if (use.where, use.full) in ALLOWED_PRIVATE_IN_TESTS:
                continue
            bad.append(f"  {use.where} (line {use.line}) uses {use.full}"
                       f" (allowed only in tests/{unit(use.module).split('.')[-1]}/)")
    assert not bad, "tests reaching private names of a subpackage outside its folder:\n" + "\n".join(bad)


def test_allowed_private_uses_still_exist():
    """An allowance whose use has gone is removed, so that the list cannot grow stale."""
    uses = {(u.where, u.full) for path in suite_files() for u in private_uses(_tree(path), _rel(path))}
    stale = sorted(set(ALLOWED_PRIVATE_IN_TESTS) - uses)
    assert not stale, f"ALLOWED_PRIVATE_IN_TESTS lists uses that are gone: {stale}"


def test_test_file_names_are_unique():
    """pytest imports test modules by file name (folders without __init__.py)."""
    names = Counter(p.name for p in suite_files() if p.name != "conftest.py")
    twice = sorted(n for n, k in names.items() if k > 1)
    assert not twice, "test files with the same name in two folders: " + ", ".join(
        f"{n} ({', '.join(_rel(p) for p in suite_files() if p.name == n)})" for n in twice)


# --------------------------------------------------------------------------- the measures
def top_modules() -> list[str]:
    """The flat modules at the top of the package."""
    return sorted(m.name for m in package_modules().values() if m.name.count(".") == 1 and not m.is_package)


def measures() -> dict[str, object]:
    """The layout's numbers, for a note: modules, cycles, private imports, the longest chain."""
    mods = package_modules()
    edges = graph()
    private = [u for name, mod in mods.items() for u in private_uses(_tree(mod.path), name, mod)]
    return {
        "modules": len(mods),
        "modules at the top": top_modules(),
        "imports between modules": sum(len(t) for t in edges.values()),
        "cycles": cycles(edges),
        "private uses within a unit": len(private) - sum(unit(u.where) != unit(u.module) for u in private),
        "private uses across units": [f"{u.where} -> {u.full}" for u in private if unit(u.where) != unit(u.module)],
        "longest chain": longest_chain(edges, exclude=[FACE]),
    }


def main() -> None:
    m = measures()
    chain = m["longest chain"]
    print(f"modules: {m['modules']}, imports between them: {m['imports between modules']}")
    print(f"modules at the top: {len(m['modules at the top'])} (at most {MAX_TOP_MODULES}): "
          f"{', '.join(x.split('.')[-1] for x in m['modules at the top'])}")
    print(f"import cycles: {len(m['cycles'])}" + "".join(f"\n  {', '.join(c)}" for c in m["cycles"]))
    print(f"private uses across units: {len(m['private uses across units'])}"
          + "".join(f"\n  {u}" for u in m["private uses across units"]))
    print(f"private uses within a unit: {m['private uses within a unit']}")
    print(f"longest chain of imports (cycles collapsed, not from {FACE}/__init__.py): {len(chain)} modules")
    print("  " + " -> ".join(chain))


if __name__ == "__main__":
    main()
