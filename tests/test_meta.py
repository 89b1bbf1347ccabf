"""Meta-tests: every hook is tested and documented; the import rules hold (no cycles, the
layers of docs/architecture.md, checked by import-linter); every keymps name the docstrings
and docs/ give exists."""

from __future__ import annotations

import ast
import importlib
import inspect
import re
from collections import defaultdict
from collections.abc import Iterator
from pathlib import Path

import pytest

from keymps.plugin import hookspecs

REPO = Path(__file__).resolve().parents[1]
HOOKS = sorted(
    name
    for name, value in vars(hookspecs).items()
    if inspect.isfunction(value) and hasattr(value, "keymps_spec")
)


def test_hookspecs_found() -> None:
    assert HOOKS == [
        "keymps_stage_done",
        "register_detectors",
        "register_executors",
        "register_image_sources",
        "register_robots",
        "register_vlm_backends",
    ]


@pytest.mark.parametrize("hook", HOOKS)
def test_every_hook_has_a_docs_heading_with_its_signature(hook: str) -> None:
    docs = (REPO / "docs/plugins.md").read_text()
    parameters = ", ".join(inspect.signature(getattr(hookspecs, hook)).parameters)
    assert f"### {hook}({parameters})" in docs


@pytest.mark.parametrize("hook", HOOKS)
def test_every_hook_is_exercised_by_a_test(hook: str) -> None:
    tests = [p for p in (REPO / "tests").rglob("test_*.py") if p.name != "test_meta.py"]
    assert any(re.search(rf"\b{hook}\b", p.read_text()) for p in tests), hook


def _import_graph() -> object:
    import grimp

    return grimp.build_graph("keymps", exclude_type_checking_imports=True)


def test_no_import_cycles_function_level_imports_included() -> None:
    """grimp sees every import statement, those inside functions too."""
    graph = _import_graph()
    modules = sorted(graph.modules)  # type: ignore[attr-defined]
    imports = {m: graph.find_modules_directly_imported_by(m) for m in modules}  # type: ignore[attr-defined]
    cycles = _cycles(imports)
    assert not cycles, "import cycles: " + "; ".join(" -> ".join(c) for c in cycles)


def _cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan), each as a cycle path."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for target in edges.get(node, ()):
            if target not in index:
                visit(target)
                low[node] = min(low[node], low[target])
            elif target in on_stack:
                low[node] = min(low[node], index[target])
        if low[node] == index[node]:
            component = []
            while True:
                member = stack.pop()
                on_stack.discard(member)
                component.append(member)
                if member == node:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for node in edges:
        if node not in index:
            visit(node)
    return found


def test_nothing_imports_the_root_package() -> None:
    """keymps/__init__.py is the users' API; inside keymps every import names its module."""
    graph = _import_graph()
    importers = graph.find_modules_that_directly_import("keymps")  # type: ignore[attr-defined]
    assert not importers, f"these modules import the root package: {sorted(importers)}"


def test_the_import_contracts_hold() -> None:
    """The layers and independence contracts in pyproject.toml ([tool.importlinter])."""
    import subprocess
    import sys

    command = "from importlinter.cli import lint_imports_command; lint_imports_command()"
    lint = subprocess.run(
        [sys.executable, "-c", command, "--no-cache"],
        capture_output=True,
        text=True,
        cwd=REPO,
        timeout=120,
    )
    assert lint.returncode == 0, lint.stdout[-3000:]


DOTTED_NAME = re.compile(r"(?<![\w./-])keymps(?:\.[A-Za-z_]\w*)+")
"""keymps.x.y as docstrings and docs write a module or an object in one (not a path)."""


def _docstrings(path: Path) -> Iterator[str]:
    """Every string statement of a module: the docstrings of it, its classes and functions,
    and those under its attributes."""
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        value = node.value if isinstance(node, ast.Expr) else None
        if isinstance(value, ast.Constant) and isinstance(value.value, str):
            yield value.value


def _dotted_names() -> dict[str, set[str]]:
    """Each dotted keymps name in the docstrings of keymps and its plugins and in docs/, with
    the files that give it."""
    found: dict[str, set[str]] = defaultdict(set)
    modules = [*(REPO / "keymps").rglob("*.py"), *(REPO / "plugins").glob("*/keymps_*/**/*.py")]
    texts = [(path, text) for path in modules for text in _docstrings(path)]
    texts += [(path, path.read_text(encoding="utf-8")) for path in (REPO / "docs").rglob("*.md")]
    for path, text in texts:
        for name in DOTTED_NAME.findall(text):
            found[name].add(str(path.relative_to(REPO)))
    return found


def _resolves(name: str) -> bool:
    """Whether `name` is a module, or an attribute or a declared field (dataclass, pydantic,
    annotated) of something in one."""
    parts = name.split(".")
    for size in range(len(parts), 0, -1):
        try:
            target: object = importlib.import_module(".".join(parts[:size]))
            break
        except ImportError:
            continue
    for part in parts[size:]:
        if hasattr(target, part):
            target = getattr(target, part)
            continue
        declared = {
            **getattr(target, "__dataclass_fields__", {}),
            **getattr(target, "model_fields", {}),
        }
        for owner in getattr(target, "__mro__", ()):
            declared.update(getattr(owner, "__annotations__", {}))
        return part in declared and part == parts[-1]
    return True


def test_the_dotted_names_in_docstrings_and_docs_exist() -> None:
    names = _dotted_names()
    assert len(names) > 50  # the search finds them: docs/ and the docstrings name many
    missing = [
        f"{name} ({', '.join(sorted(names[name]))})" for name in names if not _resolves(name)
    ]
    assert not missing, "no such keymps names: " + "; ".join(sorted(missing))


def _source_files() -> Iterator[Path]:
    yield from (REPO / "keymps").rglob("*.py")
    yield from (REPO / "plugins").glob("*/*/**/*.py")


def _private_names_defined(tree: ast.Module) -> set[str]:
    """The module's own private names: functions, classes, globals, attributes it assigns."""
    found: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            found.add(node.name)
        elif isinstance(node, ast.Name) and isinstance(node.ctx, ast.Store):
            found.add(node.id)
        elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
            found.add(node.target.id)
        elif isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Store) and _on_self(node):
            found.add(node.attr)
    return {name for name in found if name.startswith("_") and not name.startswith("__")}


def _on_self(node: ast.Attribute) -> bool:
    """`self.x` or `cls.x`: the class's own attribute."""
    return isinstance(node.value, ast.Name) and node.value.id in ("self", "cls")


def test_no_module_reaches_into_another_modules_private_names() -> None:
    """A name with a leading underscore is its module's own: other modules neither import it
    nor read or set it on an object (say what is needed with a public name instead)."""
    trees = {path: ast.parse(path.read_text(), str(path)) for path in _source_files()}
    defined = {path: _private_names_defined(tree) for path, tree in trees.items()}
    everywhere: set[str] = set().union(*defined.values())
    modules = {path.stem for path in trees}
    reaches = []
    for path, tree in trees.items():
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and (node.module or "").split(".")[0] in (
                "keymps",
                *(p.name for p in (REPO / "plugins").glob("*/keymps_*")),
            ):
                names = [a.name for a in node.names if a.name.startswith("_")]
                # a package's private module (keymps._memory) is the package's own
                names = [n for n in names if not n.startswith("__") and n not in modules]
            elif isinstance(node, ast.Attribute) and not _on_self(node):
                names = [node.attr] if node.attr in everywhere - defined[path] else []
            else:
                continue
            reaches += [f"{path.relative_to(REPO)}:{node.lineno}: {name}" for name in names]
    assert not reaches, "private names used outside their module:\n" + "\n".join(reaches)
