"""The documentation is tested like code: every ```python block of README.md and of the guide
(docs/**/*.md) runs, the Sphinx build (guide + API reference from the docstrings) has no warning, and
every public name is in the API reference with a docstring. A guide page's blocks build on each other;
each README block must run on its own, as a reader who copies one would run it."""

import importlib
import inspect
import os
import re
import subprocess
import sys
import traceback
import types
from pathlib import Path

import pytest
import taichi as ti

import taichi_anim

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs"
MARKDOWN = [ROOT / "README.md"] + sorted(p for p in DOCS.rglob("*.md") if "_build" not in p.parts)
# Pages whose blocks each run on their own: a fresh namespace, an empty folder, Taichi not initialised.
STANDALONE_BLOCKS = {ROOT / "README.md"}

# Modules whose public names the API reference must cover: their __all__, or else every public name
# defined in the module itself.
API_MODULES = [
    "taichi_anim",
    "taichi_anim.shapes",
    "taichi_anim.io",
    "taichi_anim.spatial",
    "taichi_anim.collision.neighbors",
    "taichi_anim.integrators",
    "taichi_anim.integrators.choice",
    "taichi_anim.ode",
    "taichi_anim.render",
    "taichi_anim.scenes",
    "taichi_anim.scenes.runner",
    "taichi_anim.content",
    "taichi_anim.errors",
    "taichi_anim.cli",
    "taichi_anim.stability",
    "taichi_anim.sweep",
]

_FENCE = re.compile(r"^(`{3,}|~{3,})\s*([\w+-]*)")


def python_blocks(text: str) -> list[tuple[int, str]]:
    """(first code line number, code) of each fenced block whose info string is `python`."""
    blocks, lines = [], text.splitlines()
    k = 0
    while k < len(lines):
        m = _FENCE.match(lines[k].lstrip())
        if not m:
            k += 1
            continue
        fence, lang, indent = m.group(1), m.group(2), len(lines[k]) - len(lines[k].lstrip())
        end = k + 1
        while end < len(lines) and not lines[end].strip().startswith(fence):
            end += 1
        if lang == "python":
            body = [line[indent:] for line in lines[k + 1 : end]]
            blocks.append((k + 2, "\n".join(body) + "\n"))
        k = end + 1
    return blocks


def test_block_parser_finds_blocks_and_lines():
    text = "intro\n```python\na = 1\n```\n```bash\nls\n```\n  ```python\n  b = a\n  ```\n"
    assert python_blocks(text) == [(3, "a = 1\n"), (9, "b = a\n")]


def _shown(page: Path) -> str:
    return str(page.relative_to(ROOT)) if page.is_relative_to(ROOT) else page.name


def _run_block(page: Path, source: Path, start: int, code: str, module: types.ModuleType) -> None:
    compiled = compile("\n" * (start - 1) + code, str(source), "exec")
    try:
        exec(compiled, module.__dict__)
    except Exception as e:
        tb = traceback.extract_tb(e.__traceback__)
        line = max((f.lineno for f in tb if f.filename == str(source)), default=start)
        detail = "".join(traceback.format_exception(e)[-12:])
        pytest.fail(
            f"{_shown(page)}:{line}: the python block starting at line {start} raised "
            f"{type(e).__name__}: {e}\n{detail}",
            pytrace=False,
        )


def run_page(page: Path, folder: Path, *, standalone: bool = False) -> None:
    """Run the page's python blocks in order in one module namespace, in `folder` (the caller's working
    directory). The blocks are written to a file at their line numbers in the page, so tracebacks name
    page lines and Taichi (which reads a kernel's source) finds the code.

    standalone: each block runs as if it were the whole program: in a namespace of its own, in an empty
    folder of its own under `folder`, with Taichi reset (a block that needs a backend or a precision must
    start it), so no block can lean on a name, a file or a runtime an earlier block left."""
    blocks = python_blocks(page.read_text())
    assert blocks, f"{page.name} has no python block"
    lines = [""] * (max(start + code.count("\n") for start, code in blocks) + 1)
    for start, code in blocks:
        for j, line in enumerate(code.splitlines()):
            lines[start - 1 + j] = line
    source = folder / f"_docs_{page.stem}.py"
    source.write_text("\n".join(lines) + "\n")
    groups = [[b] for b in blocks] if standalone else [blocks]
    cwd = Path.cwd()
    for k, group in enumerate(groups):
        name = f"_docs_{page.stem}" + (f"_{k}" if standalone else "")
        module = types.ModuleType(name)
        module.__file__ = str(source)
        sys.modules[name] = module  # dataclasses and Taichi look modules up by name
        try:
            if standalone:
                ti.reset()
                own = folder / f"block_{group[0][0]}"
                own.mkdir()
                os.chdir(own)
            for start, code in group:
                _run_block(page, source, start, code, module)
        finally:
            os.chdir(cwd)
            del sys.modules[name]


# Pages with examples (an index or a page of prose only has none).
PAGES = [p for p in MARKDOWN if python_blocks(p.read_text())]


# The three heaviest guide pages' examples (18-40 s each on 2 loaded cores, mostly compiling) run in the
# slow set: the scenes they build are those of the default run's rigid, contact and integrator tests.
SLOW_PAGES = {DOCS / "guide" / name for name in ("rigid.md", "contacts.md", "integrators.md")}


@pytest.mark.parametrize(
    "page",
    [pytest.param(p, marks=pytest.mark.slow) if p in SLOW_PAGES else p for p in PAGES],
    ids=[_shown(p) for p in PAGES],
)
def test_examples_run(page, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    run_page(page, tmp_path, standalone=page in STANDALONE_BLOCKS)


def test_a_failing_block_names_its_line(tmp_path):
    page = tmp_path / "page.md"
    page.write_text("# t\n\n```python\nx = 1\n```\n\n```python\ny = x + 1\nassert y == 3\n```\n")
    with pytest.raises(pytest.fail.Exception, match=r"page.md:9: the python block starting at line 8"):
        run_page(page, tmp_path)


def test_standalone_blocks_share_no_name_file_or_runtime(tmp_path, monkeypatch):
    """A block leaning on an earlier block's name, file or Taichi runtime passes on a guide page and
    fails where blocks must run on their own (the README)."""
    monkeypatch.chdir(tmp_path)
    leaning = {
        "name": ("x = 1", "y = x + 1", "NameError: name 'x' is not defined"),
        "file": ("open('a.txt', 'w').write('1')", "open('a.txt').read()", "FileNotFoundError"),
        "runtime": (
            "import taichi_anim as ta\nta.init('cpu', precision='f64')",
            "import taichi_anim as ta\nassert ta.is_initialized()",
            "AssertionError",
        ),
    }
    for what, (first, second, error) in leaning.items():
        page, folder = tmp_path / f"{what}.md", tmp_path / what
        folder.mkdir()
        page.write_text(f"# t\n\n```python\n{first}\n```\n\n```python\n{second}\n```\n")
        run_page(page, folder)  # one namespace, folder and runtime: passes
        with pytest.raises(pytest.fail.Exception, match=error):
            run_page(page, folder, standalone=True)


@pytest.fixture(scope="module")
def built_docs(tmp_path_factory):
    """Build the HTML guide once; any Sphinx warning (a broken docstring, link or directive) fails."""
    out = tmp_path_factory.mktemp("html")
    run = subprocess.run(
        [sys.executable, "-m", "sphinx", "-b", "html", "-W", "--keep-going", "-q", "-E", str(DOCS), str(out)],
        capture_output=True,
        text=True,
        cwd=ROOT,
    )
    return run, out


def test_sphinx_builds_without_warnings(built_docs):
    run, out = built_docs
    assert run.returncode == 0, f"sphinx-build failed:\n{run.stderr[-6000:]}"
    assert (out / "index.html").is_file()


def public_names(module_name: str) -> list[str]:
    module = importlib.import_module(module_name)
    names = getattr(module, "__all__", None)
    if names is None:
        names = [
            n
            for n, obj in vars(module).items()
            if not n.startswith("_") and getattr(obj, "__module__", None) == module_name
        ]
    return [n for n in names if not inspect.ismodule(getattr(module, n))]


def documented_ids(out: Path) -> set[str]:
    ids: set[str] = set()
    for page in (out / "api").glob("*.html"):
        ids.update(re.findall(r'<dt class="sig sig-object py" id="([^"]+)"', page.read_text()))
    return ids


def test_every_public_name_is_in_the_reference_with_a_docstring(built_docs):
    run, out = built_docs
    assert run.returncode == 0, "the docs did not build (see test_sphinx_builds_without_warnings)"
    ids = documented_ids(out)
    assert "taichi_anim.Builder.add_cloth_grid" in ids  # the page parser sees methods too
    missing, undocumented = [], []
    for module_name in API_MODULES:
        module = importlib.import_module(module_name)
        for name in public_names(module_name):
            obj = getattr(module, name)
            full = f"{module_name}.{name}"
            # A name re-exported by the top-level package is documented once, under that name.
            top = f"taichi_anim.{name}" if getattr(taichi_anim, name, None) is obj else full
            if not {full, top} & ids:
                missing.append(full)
            if (inspect.isclass(obj) or inspect.isroutine(obj)) and not inspect.getdoc(obj):
                undocumented.append(full)
    assert not missing, f"public names absent from the API reference: {missing}"
    assert not undocumented, f"public functions/classes without a docstring: {undocumented}"


def public_classes() -> list[type]:
    classes = []
    for module_name in API_MODULES:
        module = importlib.import_module(module_name)
        for name in public_names(module_name):
            obj = getattr(module, name)
            if inspect.isclass(obj) and obj not in classes:
                classes.append(obj)
    return classes


def test_public_methods_have_docstrings():
    """Every public method and property of a public class, inherited ones included, says what it does."""
    undocumented = set()
    for cls in public_classes():
        for name in dir(cls):
            if name.startswith("_"):
                continue
            owner = next((c for c in cls.__mro__ if name in vars(c)), None)
            if owner is None or not owner.__module__.startswith("taichi_anim"):
                continue
            attr = vars(owner)[name]
            if not (callable(attr) or isinstance(attr, (property, staticmethod, classmethod))):
                continue
            if not inspect.getdoc(getattr(cls, name)) and not inspect.getdoc(attr):
                undocumented.add(f"{owner.__module__}.{owner.__qualname__}.{name}")
    assert not undocumented, f"public methods without a docstring: {sorted(undocumented)}"
