"""The package's import structure, read from the source with `ast` (nothing is imported):
(a) the package's own modules are imported at module level, never inside a function, unless the import
    carries a `# cycle: <reason>` comment;
(b) every module-level import goes down or sideways in LAYERS, never up;
(c) the module-level imports have no cycle (strongly connected components of the import graph).
An import under `if TYPE_CHECKING:` never runs: it counts for (b), not for (c).

A cycle hidden by a function-local import still exists; it only fails later and somewhere else. Third-party
libraries that are slow to import (open3d, matplotlib, imageio, scipy, pxr) are another matter: ruff's
TID253 keeps them inside the functions that use them, and this file does not look at them."""

import ast
from dataclasses import dataclass
from fnmatch import fnmatch
from pathlib import Path

import pytest

PACKAGE = "taichi_anim"
PACKAGE_DIR = Path(__file__).resolve().parent.parent / PACKAGE

# Lowest first. A module imports only from its own layer or lower ones. Entries are module paths
# relative to the package; the longest entry that names a module or one of its packages places it, and
# "" is the package's own __init__ (the public names) only.
LAYERS = [
    # foundations: errors, argument checks, the Taichi runtime, the failure policy, signals
    # (capacity: the size buckets and field pool the runtime's init switches; frontend: Taichi's front end
    # made cheaper and tensor_ops: its vector operations built into the IR, both installed by the runtime;
    # bulk: many fields written in one launch; workers: passes of one launch meeting at barriers)
    (
        "errors",
        "validate",
        "rng",
        "capacity",
        "frontend",
        "tensor_ops",
        "runtime",
        "bulk",
        "workers",
        "health",
        "interrupts",
        "compile_clock",
        "device_probe",
    ),  # fmt: skip
    # file formats and atomic writes of plain arrays (no model, no scene)
    ("io.atomic", "io.read_guard", "io.obj_scan", "io.export", "io.lock", "io.manifest"),
    # meshes and cloth materials from arrays or files; what a frame shows (plain data: points, meshes,
    # lines), which body kinds make and io/, render/ and the viewer read
    # (shapes: rigid bodies' shapes and their mass properties)
    ("rotations", "geometry", "cloth", "content", "shapes"),
    # geometry queries, prefix sums, matrix-free linear solvers
    ("spatial", "linalg"),
    # the parts a scene is made of: force terms, colliders and contacts, particle sources, body kinds
    ("terms", "collision", "particles", "bodies", "blobs.blocks"),
    # the blobs: the field owns its extractors, the extractors share only the block tiling
    ("blobs.tetrahedra",),
    ("blobs.isosurface",),
    ("blobs.field", "blobs"),
    # what a built scene is
    ("watchdog", "model", "state", "builder"),
    # who advances it
    ("stability", "finish", "solvers", "integrators", "stepper", "statics"),
    ("ode",),
    # who reads a frame: USD, pictures, video, the window
    ("io", "io.usd", "render", "viewer"),
    # the public names
    ("",),
    # the demo catalogue and the command line
    ("scenes",),
    # many runs of a scene, each in a process of its own
    ("sweep",),
    ("cli", "__main__"),
]

# Files exempt from the three checks (fnmatch patterns, relative to the package): none. The mechanism stays
# so that a large move can land in steps; test_allowed_files_still_need_their_exemption keeps it empty
# once the files are clean.
ALLOWED: tuple[str, ...] = ()


@dataclass(frozen=True)
class Import:
    """One import statement of the package's own modules, resolved: `targets` are module names."""

    module: str
    file: str
    line: int
    targets: tuple[str, ...]
    local: bool  # inside a function
    type_only: bool  # under `if TYPE_CHECKING:` (never runs)
    cycle_note: bool  # carries a `# cycle: <reason>` comment


def module_files(package_dir: Path, package: str) -> dict[str, Path]:
    """Module name -> file, for every .py file of the package."""
    out = {}
    for path in sorted(package_dir.rglob("*.py")):
        parts = [package, *path.relative_to(package_dir).with_suffix("").parts]
        if parts[-1] == "__init__":
            parts.pop()
        out[".".join(parts)] = path
    return out


def _resolve(module: str, is_package: bool, node, modules: dict, package: str) -> tuple[str, ...]:
    """The package modules an Import/ImportFrom node names (a name that is not a module names its
    package)."""
    if isinstance(node, ast.Import):
        return tuple(a.name for a in node.names if a.name == package or a.name.startswith(package + "."))
    if node.level:
        base = module.split(".") if is_package else module.split(".")[:-1]
        base = base[: len(base) - (node.level - 1)]
        source = ".".join(base + ([node.module] if node.module else []))
    else:
        source = node.module or ""
    if source != package and not source.startswith(package + "."):
        return ()
    return tuple(f"{source}.{a.name}" if f"{source}.{a.name}" in modules else source for a in node.names)


def _is_type_checking(test) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
    )


def _has_cycle_note(lines: list[str], node) -> bool:
    """A `# cycle:` comment with a reason on the import's lines or on the line just above."""
    first = max(node.lineno - 2, 0)
    for text in lines[first : node.end_lineno]:
        note = text.partition("# cycle:")[2]
        if note.strip():
            return True
    return False


def _imports_of(module: str, path: Path, package_dir: Path, modules: dict, package: str) -> list[Import]:
    source = path.read_text()
    lines = source.splitlines()
    rel = path.relative_to(package_dir).as_posix()
    found = []

    def visit(node, local, type_only):
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.Import, ast.ImportFrom)):
                targets = _resolve(module, path.name == "__init__.py", child, modules, package)
                if targets:
                    note = _has_cycle_note(lines, child)
                    found.append(Import(module, rel, child.lineno, targets, local, type_only, note))
                continue
            inner_local = local or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda))
            guarded = type_only or (isinstance(child, ast.If) and _is_type_checking(child.test))
            visit(child, inner_local, guarded)

    visit(ast.parse(source, str(path)), False, False)
    return found


def package_imports(package_dir: Path = PACKAGE_DIR, package: str = PACKAGE) -> list[Import]:
    """Every import of the package's own modules, in every module of the package."""
    modules = module_files(package_dir, package)
    return [
        i
        for module, path in modules.items()
        for i in _imports_of(module, path, package_dir, modules, package)
    ]


def layer_of(module: str, package: str = PACKAGE, layers=LAYERS) -> int | None:
    """Index in `layers` of the longest entry naming `module` or one of its packages (None: unplaced)."""
    rel = module[len(package) + 1 :] if module != package else ""
    best, best_len = None, -1
    for k, entries in enumerate(layers):
        for entry in entries:
            named = rel == entry if entry == "" else rel == entry or rel.startswith(entry + ".")
            if named and len(entry) > best_len:
                best, best_len = k, len(entry)
    return best


def allowed(file: str, patterns=ALLOWED) -> bool:
    """Whether `file` (relative to the package) is exempt."""
    return any(fnmatch(file, p) for p in patterns)


def local_imports(imports: list[Import], exempt=()) -> list[str]:
    """Function-local imports of package modules without a `# cycle:` reason."""
    return [
        f"{i.file}:{i.line} imports {', '.join(sorted(set(i.targets)))} inside a function"
        for i in imports
        if i.local and not i.cycle_note and not allowed(i.file, exempt)
    ]


def upward_imports(imports: list[Import], package: str = PACKAGE, layers=LAYERS, exempt=()):
    """Module-level imports of a module in a higher layer."""
    bad = []
    for i in imports:
        if i.local or allowed(i.file, exempt):
            continue
        own = layer_of(i.module, package, layers)
        for target in sorted(set(i.targets)):
            theirs = layer_of(target, package, layers)
            if own is not None and theirs is not None and theirs > own:  # unplaced: see the layer test
                bad.append(f"{i.file}:{i.line} ({layers[own]}) imports {target} from a higher layer")
    return bad


def import_graph(imports: list[Import], package: str = PACKAGE) -> dict[str, set[str]]:
    """What importing each module runs first, at module level: the modules it names, and the packages
    (their __init__) above each of them that are not already being imported around the importer."""
    graph: dict[str, set[str]] = {}
    for i in imports:
        edges = graph.setdefault(i.module, set())
        if i.local or i.type_only:
            continue
        own_packages = {i.module.rsplit(".", k)[0] for k in range(1, i.module.count(".") + 1)}
        for target in i.targets:
            edges.add(target)
            parts = target.split(".")
            for k in range(1, len(parts)):
                parent = ".".join(parts[:k])
                if parent not in own_packages and parent != package:
                    edges.add(parent)
        edges.discard(i.module)
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan 1972, iterative)."""
    index, low, on_stack, stack, found = {}, {}, set(), [], []
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph.get(root, ()))))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            v, children = work[-1]
            w = next(children, None)
            if w is not None:
                if w not in index:
                    index[w] = low[w] = len(index)
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(sorted(graph.get(w, ())))))
                elif w in on_stack:
                    low[v] = min(low[v], index[w])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[v])
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
    return found


def _allowed_modules(package_dir: Path = PACKAGE_DIR, package: str = PACKAGE) -> set[str]:
    return {
        m
        for m, p in module_files(package_dir, package).items()
        if allowed(p.relative_to(package_dir).as_posix())
    }


# ------------------------------------------------------------------------------------------- the package


@pytest.fixture(scope="module")
def imports():
    return package_imports()


def test_every_module_has_a_layer():
    unplaced = [m for m in module_files(PACKAGE_DIR, PACKAGE) if layer_of(m) is None]
    assert not unplaced, f"add these modules to LAYERS: {unplaced}"


def test_no_function_local_imports_of_the_package(imports):
    bad = local_imports(imports, ALLOWED)
    assert not bad, "\n".join(bad)


def test_no_upward_imports(imports):
    bad = upward_imports(imports, exempt=ALLOWED)
    assert not bad, "\n".join(bad)


def test_no_import_cycles(imports):
    exempt = _allowed_modules()
    found = [c for c in cycles(import_graph(imports)) if not exempt & set(c)]
    assert not found, "\n".join(" -> ".join(c) for c in found)


def test_allowed_files_still_need_their_exemption(imports):
    """An entry of ALLOWED whose files have all become clean leaves the list, so that the checks cover
    them again."""
    in_cycles = {m for c in cycles(import_graph(imports)) for m in c}
    needed = set()
    for i in imports:
        upward = not i.local and bool(upward_imports([i]))
        if (i.local and not i.cycle_note) or upward or i.module in in_cycles:
            needed.add(i.file)
    clean = [p for p in ALLOWED if not any(fnmatch(f, p) for f in needed)]
    assert not clean, f"remove from ALLOWED, they pass now: {clean}"


# ------------------------------------------------------------------------ the checks on a made-up package


def _package(tmp_path: Path, files: dict[str, str]) -> Path:
    root = tmp_path / "pkg"
    for name, text in {"__init__.py": "", **files}.items():
        (root / name).parent.mkdir(parents=True, exist_ok=True)
        (root / name).write_text(text)
    return root


def test_checks_find_a_local_import_an_upward_import_and_a_cycle(tmp_path):
    root = _package(
        tmp_path,
        {
            "low.py": "from . import high\n",  # upward, and low <-> high is a cycle
            "high.py": "from .low import x\n\ndef f():\n    from . import low\n",  # local import
            "noted.py": "def f():\n    from . import high  # cycle: high imports noted at module level\n",
            "sub/__init__.py": "from . import leaf\n",
            "sub/leaf.py": "from .. import low\n",
            "guarded.py": "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from . import top\n",
            "top.py": "import pkg.guarded\n",
        },
    )
    layers = [("low", "sub"), ("high", "noted", "guarded", "top"), ("",)]
    found = package_imports(root, "pkg")
    assert local_imports(found) == ["high.py:4 imports pkg.low inside a function"]
    assert upward_imports(found, "pkg", layers) == [
        "low.py:1 (('low', 'sub')) imports pkg.high from a higher layer"
    ]
    graph = import_graph(found, "pkg")
    # A TYPE_CHECKING import never runs, so guarded <-> top is no cycle; the submodule's import of its
    # own package's sibling is an edge, its package is not (it is being imported around it).
    assert cycles(graph) == [["pkg.high", "pkg.low"]]
    assert graph["pkg.sub.leaf"] == {"pkg.low"}
    assert layer_of("pkg", "pkg", layers) == 2 and layer_of("pkg.sub.leaf", "pkg", layers) == 0


def test_importing_a_submodule_runs_its_package_first(tmp_path):
    """a -> b.c runs b/__init__ first, and b/__init__ -> a closes a cycle that no module names twice."""
    root = _package(
        tmp_path,
        {"a.py": "from .b.c import x\n", "b/__init__.py": "from .. import a\n", "b/c.py": "x = 1\n"},
    )
    assert cycles(import_graph(package_imports(root, "pkg"), "pkg")) == [["pkg.a", "pkg.b"]]
