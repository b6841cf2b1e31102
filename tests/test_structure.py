"""The code base's shape: imports run one way, one implementation of each shared job.

Walks the sources with :mod:`ast` (no imports are executed):

* no import cycle among the project's modules, counting imports inside
  functions and the names :mod:`slicer` loads on first use;
* imports run one way: core <- outputs <- validation <- job and CLI
  (:data:`LAYERS`);
* no function-level import of the project's own modules;
* Numba only in ``slicer/_kernels/`` and ``slicer/_jit.py``, thread counts
  only in ``slicer/_kernels/runtime/launch.py``;
* temporary files and renames (atomic publication) only in ``slicer/atomic.py``;
* no module in ``tests/`` imports a test module (``test_*``, ``conftest``): what tests
  share lives in ``tests/helpers.py`` and ``tests/format_readers.py``, shared fixtures
  in ``tests/conftest.py``.
"""
from __future__ import annotations

import ast
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("slicer", "formats", "validation", "sample_lattices")

#: module name prefix -> layer; a module may import only modules of its own or a lower layer.
#: The longest matching prefix wins.
LAYERS = {
    "slicer.job": 3, "slicer.cli": 3, "slicer.__main__": 3,
    "validation": 2,
    "validation.parts_bench": 3,      # times the whole slice job (run_slice)
    "formats": 1, "sample_lattices": 1,
    "slicer.raster.antialias": 1, "slicer.contours": 1, "slicer.render.output": 1,
    "slicer.raster.placed_layers": 1, "slicer.viewer": 1,
    "slicer.printability": 1,         # reads back written layers (formats.readback)
    "slicer.supports.build": 1, "slicer.supports.points": 1, "slicer.supports.trees": 1,   # the check's island finder
    "slicer.meshing": 1,              # mesh and 3MF outputs (formats.threemf_slices' package parts)
}
#: every other slicer.* module is core (layer 0)
NAMES = {0: "core", 1: "outputs", 2: "validation", 3: "job/CLI"}


def _sources() -> dict[str, Path]:
    files = subprocess.run(["git", "ls-files", "--cached", "--others", "--exclude-standard", *PACKAGES], cwd=ROOT, capture_output=True, text=True,
                           check=True).stdout.split()
    mods = {}
    for f in files:
        if not f.endswith(".py"):
            continue
        parts = Path(f).with_suffix("").parts
        name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        mods[name] = ROOT / f
    return mods


MODULES = _sources()


def layer(mod: str) -> int:
    if mod == "slicer":            # the package facade re-exports the job-level API
        return 3
    best, rank = "", 0
    for prefix, r in LAYERS.items():
        if (mod == prefix or mod.startswith(prefix + ".") or mod.startswith(prefix + "_")) and len(prefix) > len(best):
            best, rank = prefix, r
    if not best and mod.split(".")[0] != "slicer":
        raise AssertionError(f"{mod}: no layer assigned")
    return rank


def _is_type_checking(node: ast.If) -> bool:
    t = node.test
    return (isinstance(t, ast.Name) and t.id == "TYPE_CHECKING") or \
        (isinstance(t, ast.Attribute) and t.attr == "TYPE_CHECKING")


def _targets(mod: str, node) -> list[str]:
    """Project modules an import statement of ``mod`` loads."""
    out = []
    if isinstance(node, ast.Import):
        names = [a.name for a in node.names]
    else:
        if node.level:
            base = mod.split(".")
            if MODULES[mod].name != "__init__.py":
                base = base[:-1]
            base = base[:len(base) - (node.level - 1)]
            tgt = ".".join(base + ([node.module] if node.module else []))
        else:
            tgt = node.module or ""
        names = [f"{tgt}.{a.name}" if f"{tgt}.{a.name}" in MODULES else tgt for a in node.names]
    for n in names:
        while n and n not in MODULES:
            n = n.rpartition(".")[0]
        if n and n != mod:
            out.append(n)
    return out


def _imports(mod: str):
    """(target, line, inside a function) for every project import of ``mod``."""
    tree = ast.parse(MODULES[mod].read_text(encoding="utf-8"), str(MODULES[mod]))
    found = []

    def visit(node, in_function):
        if isinstance(node, ast.If) and _is_type_checking(node):
            return                                   # annotations only: never executed
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            found.extend((t, node.lineno, in_function) for t in _targets(mod, node))
        inner = in_function or isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda))
        for child in ast.iter_child_nodes(node):
            visit(child, inner)

    visit(tree, False)
    if mod == "slicer":                              # names loaded on first use (slicer.__getattr__)
        for node in ast.walk(tree):
            if isinstance(node, ast.Assign) and any(getattr(t, "id", None) == "_LAZY" for t in node.targets):
                found.extend((ast.literal_eval(v), node.lineno, False) for v in node.value.values)
    return found


GRAPH = {m: _imports(m) for m in MODULES}


def test_the_walk_sees_the_known_edges():
    """Guard the walker itself: it must see module-level, relative and lazy imports."""
    edges = {m: {t for t, _, _ in GRAPH[m]} for m in GRAPH}
    assert "slicer.model.skeleton" in edges["slicer.scene.read"]
    assert "slicer.errors" in edges["formats.base"] or "slicer.atomic" in edges["formats.base"]
    assert "slicer.job.run" in edges["slicer"]


def _cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    index, low, stack, on, out = {}, {}, [], set(), []
    counter = [0]

    def strong(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in sorted(edges.get(v, ())):
            if w not in index:
                strong(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(edges):
        if v not in index:
            strong(v)
    return out


def test_no_import_cycles():
    edges = {m: {t for t, _, _ in GRAPH[m]} for m in GRAPH}
    assert _cycles(edges) == []


def test_cycle_finder_finds_a_cycle():
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


def test_imports_run_one_way():
    bad = [f"{m} ({NAMES[layer(m)]}) imports {t} ({NAMES[layer(t)]}) at line {line}"
           for m, items in GRAPH.items() for t, line, _ in items if layer(t) > layer(m)]
    assert bad == []


def test_no_function_level_imports_of_project_modules():
    bad = [f"{MODULES[m].relative_to(ROOT)}:{line}: imports {t} inside a function"
           for m, items in GRAPH.items() for t, line, inside in items if inside]
    assert bad == []


def _names_used(path: Path):
    """(dotted name, line) of every import and every ``a.b`` attribute use in a file."""
    tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            yield from ((a.name, node.lineno) for a in node.names)
        elif isinstance(node, ast.ImportFrom) and not node.level:
            yield node.module or "", node.lineno
            yield from ((f"{node.module}.{a.name}", node.lineno) for a in node.names)
        elif isinstance(node, ast.Attribute):
            base = node.value.id if isinstance(node.value, ast.Name) else "?"
            yield f"{base}.{node.attr}", node.lineno


def _matches(name: str, needle: str) -> bool:
    return name == needle or name.startswith(needle + ".") or name.endswith("." + needle.rpartition(".")[2]) \
        and "." not in needle


@pytest.mark.parametrize("needle, allowed", [
    ("numba", ("slicer/_kernels/", "slicer/_jit.py")),
    ("set_num_threads", ("slicer/_kernels/runtime/launch.py",)),
    ("tempfile.mkstemp", ("slicer/atomic.py",)),
    ("tempfile.mkdtemp", ("slicer/atomic.py",)),
    ("os.replace", ("slicer/atomic.py",)),         # publication (rename over the target) is atomic.py's job
    ("os.rename", ("slicer/atomic.py",)),
])
def test_one_place_for(needle, allowed):
    bad = [f"{path.relative_to(ROOT)}:{line}: {name}"
           for path in MODULES.values() if not str(path.relative_to(ROOT)).startswith(allowed)
           for name, line in _names_used(path) if _matches(name, needle)]
    assert bad == []


def test_one_place_for_sees_uses():
    """Guard the matcher: it must catch the forms the rules are about."""
    assert _matches("numba.prange", "numba") and _matches("numba", "numba")
    assert _matches("numba.set_num_threads", "set_num_threads")
    assert _matches("os.replace", "os.replace") and not _matches("s.replace", "os.replace")
    assert not _matches("numbagg", "numba")



#: the size a compiled kernel function may reach: kernels are plain loops made
#: of small named helpers
KERNEL_MAX_LINES = 80
KERNEL_MAX_PARAMS = 15
#: the two ray walks, still over the line limit (lines, parameters): each may
#: shrink but not grow, and leaves this list once it fits. Split into helpers
#: that all take the walk's arrays, they measured 1.4-2.8x slower: Numba
#: reference-counts every array passed at every call (docs/development.md,
#: "Why the walk's arrays travel loose")
KERNEL_OVERSIZED: dict[str, tuple[int, int]] = {}


def _function_sizes(tree: ast.AST, where: str) -> dict[str, tuple[int, int]]:
    return {f"{where}:{node.name}": (node.end_lineno - node.lineno + 1,
                                     len(node.args.args) + len(node.args.kwonlyargs))
            for node in ast.walk(tree) if isinstance(node, ast.FunctionDef)}


def _oversized(sizes: dict[str, tuple[int, int]], allowed: dict[str, tuple[int, int]]) -> list[str]:
    """Functions over the limits beyond what ``allowed`` grants them, and
    entries of ``allowed`` that now fit (or are gone)."""
    bad = []
    for name, (lines, params) in sizes.items():
        lim = allowed.get(name, (KERNEL_MAX_LINES, KERNEL_MAX_PARAMS))
        lim = (max(lim[0], KERNEL_MAX_LINES), max(lim[1], KERNEL_MAX_PARAMS))
        if lines > lim[0] or params > lim[1]:
            bad.append(f"{name}: {lines} lines, {params} parameters")
    for name in allowed:
        lines, params = sizes.get(name, (0, 0))
        if lines <= KERNEL_MAX_LINES and params <= KERNEL_MAX_PARAMS:
            bad.append(f"{name}: fits now; drop it from KERNEL_OVERSIZED")
    return bad


def test_kernel_functions_stay_small():
    """No function in ``slicer/_kernels/`` is over KERNEL_MAX_LINES lines
    (docstring included) or takes over KERNEL_MAX_PARAMS parameters, except
    the listed ray walks, which may not grow."""
    kernels = ROOT / "slicer" / "_kernels"
    files = sorted(kernels.rglob("*.py"))
    assert len(files) > 10
    sizes = {}
    for f in files:
        sizes.update(_function_sizes(ast.parse(f.read_text(encoding="utf-8")), f.relative_to(kernels).as_posix()))
    assert _oversized(sizes, KERNEL_OVERSIZED) == []


def test_kernel_size_check_sees_long_wide_grown_and_stale():
    """Guard the check: a long function, a wide one, a listed one that grew
    and a listed one that fits are all reported; a small one is not."""
    long_body = "def f(a):\n" + "    a += 1\n" * KERNEL_MAX_LINES
    wide = "def g(" + ", ".join(f"p{i}" for i in range(KERNEL_MAX_PARAMS + 1)) + "):\n    pass\n"
    sizes = _function_sizes(ast.parse(long_body + wide + "def h(a, b):\n    return a\n"), "x.py")
    assert len(_oversized(sizes, {})) == 2
    assert _oversized({"x.py:f": (100, 3)}, {"x.py:f": (100, 3)}) == []
    assert len(_oversized({"x.py:f": (101, 3)}, {"x.py:f": (100, 3)})) == 1
    assert len(_oversized({"x.py:f": (60, 3)}, {"x.py:f": (100, 3)})) == 1


#: at most this many modules side by side at the top of a package; the rest live in folders named after
#: their concepts (docs/development.md, "Code layout")
TOP_MODULES = {"slicer": 12, "slicer/_kernels": 8}


@pytest.mark.parametrize("package", sorted(TOP_MODULES))
def test_packages_keep_few_modules_at_the_top(package):
    """The top of ``slicer/`` and of ``slicer/_kernels/`` stays small: a newcomer finds each concept by its
    folder's name, and every folder is a package."""
    top = ROOT / package
    modules = sorted(f.name for f in top.glob("*.py"))
    assert len(modules) <= TOP_MODULES[package], modules
    folders = [d for d in top.iterdir() if d.is_dir() and d.name != "__pycache__"]
    assert folders and all((d / "__init__.py").exists() for d in folders), folders


#: modules pytest loads itself (collected test files, conftest.py): a module of tests/ never imports one
TESTS = ROOT / "tests"
TEST_MODULES = {f.stem for f in TESTS.glob("test_*.py")} | {"conftest"}


def _test_module(name: str, modules: set[str]) -> bool:
    """``name`` (a module, or a path or file name passed to a loader) names one of ``modules``."""
    return name.split(".")[0] in modules or Path(name).name in {f"{m}.py" for m in modules}


def _test_imports(source: str, modules: set[str]) -> list[tuple[str, int]]:
    """(name, line) of every import of one of ``modules`` in ``source``: ``import`` and
    ``from ... import`` at any depth, and a module named in a call's arguments (loaded
    by path or through :mod:`importlib`)."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            names = [node.module] if node.module else [a.name for a in node.names]
        elif isinstance(node, ast.Call):
            names = [a.value for a in [*node.args, *(k.value for k in node.keywords)]
                     if isinstance(a, ast.Constant) and isinstance(a.value, str)]
        else:
            continue
        found += [(n, node.lineno) for n in names if _test_module(n, modules)]
    return sorted(found, key=lambda f: f[1])


def test_test_modules_do_not_import_each_other():
    """No module in ``tests/`` imports a test module or ``conftest``: a piece two test
    files need goes to ``tests/helpers.py`` (the format readers to
    ``tests/format_readers.py``), a shared fixture to ``tests/conftest.py``."""
    files = sorted(TESTS.glob("*.py"))
    assert len(files) > 50 and "test_structure" in TEST_MODULES
    bad = [f"{f.relative_to(ROOT)}:{line}: imports {name}" for f in files
           for name, line in _test_imports(f.read_text(encoding="utf-8"), TEST_MODULES - {f.stem})]
    assert bad == []


def test_test_import_check_sees_every_form():
    """Guard the check: plain, from-, nested and relative imports of a test module or
    conftest, and loading one by name or path, are all reported; other modules are not."""
    mods = {"test_a", "conftest"}
    source = """
import test_a
import test_a.sub as s
from test_a import x
from conftest import missing_tool
from . import test_a


def f():
    from test_a import y
    importlib.import_module("test_a")
    spec_from_file_location("m", Path(__file__).with_name("test_a.py"))
    load_sibling("test_a")
    load(path="tests/conftest.py")
"""
    assert [line for _, line in _test_imports(source, mods)] == [2, 3, 4, 5, 6, 10, 11, 12, 13, 14]
    clean = """
import helpers
from helpers import run
from format_readers import read_ctb
import test_b
tmp_path_factory.mktemp("test_a_out")
print("see test_a")
"""
    assert _test_imports(clean, mods) == []
