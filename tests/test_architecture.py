"""The source tree keeps its shape (docs/architecture.md): imports at module top, short functions,
layers that point down, matplotlib only in packlab.viz, typed records.

Each test reads the source with ``ast`` (nothing is imported but packlab itself) and lists every
offender, so one run shows all there is to fix.
"""

from __future__ import annotations

import ast
import importlib.util
import re
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

import packlab

PACKAGE_DIR = Path(packlab.__file__).resolve().parent
REPO_ROOT = PACKAGE_DIR.parents[1]

#: Optional heavy dependencies (extras) that may be imported inside a function, so that the
#: core installs and imports without them. Their submodules count too.
LAZY_IMPORTS_ALLOWED = frozenset(
    {
        "torch",
        "transformers",
        "peft",
        "accelerate",
        "ray",
        "datasets",
        "stable_baselines3",
        "sb3_contrib",
        "openai",
        "jinja2",
        "rerun",
        "plotly",
        # Core, but ~0.1 s to import: opened when a learned policy loads its graphs.
        "onnxruntime",
    }
)
MAX_FUNCTION_LINES = 80
#: The paths ``ruff check`` covers; its settings are pyproject's [tool.ruff].
RUFF_PATHS = ("src", "tests", "benchmarks", "scripts")
FUNCTION_NODES = (ast.FunctionDef, ast.AsyncFunctionDef)


def _modules() -> Iterator[tuple[str, ast.Module]]:
    """(dotted module name, parsed tree) of every module under src/packlab."""
    for path in sorted(PACKAGE_DIR.rglob("*.py")):
        parts = path.relative_to(PACKAGE_DIR.parent).with_suffix("").parts
        if parts[-1] == "__init__":
            parts = parts[:-1]
        yield ".".join(parts), ast.parse(path.read_text(encoding="utf-8"), filename=str(path))


def _functions(tree: ast.AST, prefix: str = "") -> Iterator[tuple[str, ast.AST]]:
    """(qualified name, node) of every function and method, nested ones included."""
    for node in ast.iter_child_nodes(tree):
        if isinstance(node, FUNCTION_NODES):
            name = f"{prefix}{node.name}"
            yield name, node
            yield from _functions(node, f"{name}.")
        elif isinstance(node, ast.ClassDef):
            yield from _functions(node, f"{prefix}{node.name}.")
        else:
            yield from _functions(node, prefix)


def _own_body(function: ast.AST) -> Iterator[ast.AST]:
    """The nodes of a function's body, not descending into nested functions or classes."""
    for node in ast.iter_child_nodes(function):
        yield node
        if not isinstance(node, (*FUNCTION_NODES, ast.ClassDef, ast.Lambda)):
            yield from _own_body(node)


def _imported(node: ast.Import | ast.ImportFrom, module: str) -> list[str]:
    """Absolute names of the modules an import statement reads."""
    if isinstance(node, ast.Import):
        return [alias.name for alias in node.names]
    if node.level:
        package = module.split(".")
        base = package[: len(package) - node.level + (1 if _is_package(module) else 0)]
        return [".".join([*base, node.module] if node.module else base)]
    return [node.module or ""]


def _is_package(module: str) -> bool:
    return (PACKAGE_DIR.parent.joinpath(*module.split(".")) / "__init__.py").exists()


def _all_imports(tree: ast.AST, module: str) -> Iterator[tuple[str, int]]:
    """(imported module, line) of every import statement in a module, at any depth."""
    for node in ast.walk(tree):
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            for name in _imported(node, module):
                yield name, node.lineno


def test_no_imports_inside_functions_except_optional_heavy_dependencies():
    offenders = []
    for module, tree in _modules():
        for qualname, function in _functions(tree):
            for node in _own_body(function):
                if not isinstance(node, (ast.Import, ast.ImportFrom)):
                    continue
                for name in _imported(node, module):
                    if name.split(".")[0] not in LAZY_IMPORTS_ALLOWED:
                        offenders.append(f"{module}:{qualname}:{name} (line {node.lineno})")
    assert not offenders, (
        "imports inside functions (move them to the module top; only optional heavy "
        "dependencies may be imported lazily):\n  " + "\n  ".join(offenders)
    )


def test_functions_are_at_most_80_lines():
    offenders = []
    for module, tree in _modules():
        for qualname, function in _functions(tree):
            lines = function.end_lineno - function.lineno + 1
            if lines > MAX_FUNCTION_LINES:
                offenders.append(f"{module}:{qualname} ({lines} lines, line {function.lineno})")
    assert not offenders, (
        f"functions longer than {MAX_FUNCTION_LINES} lines (def line to last line):\n  "
        + "\n  ".join(offenders)
    )


def test_import_linter_contract_is_kept():
    pytest.importorskip("importlinter", reason="import-linter is in the test extra")
    script = Path(sys.executable).with_name("lint-imports")
    if script.exists():
        command = [str(script), "--no-cache", "--no-logo"]
    else:  # the console script is not beside this interpreter: the same check through its API
        api = (
            "import sys; from importlinter.cli import lint_imports; "
            "sys.exit(lint_imports(no_cache=True, no_logo=True))"
        )
        command = [sys.executable, "-c", api]
    done = subprocess.run(
        command, cwd=REPO_ROOT, capture_output=True, text=True, timeout=300, check=False
    )
    report = done.stdout + done.stderr
    assert done.returncode == 0, f"lint-imports failed (exit {done.returncode}):\n{report}"
    assert re.search(r"\b0 broken\b", report), report


def test_ruff_check_passes():
    """``ruff check`` (pyproject: the defaults, the 100-character line limit, sorted imports)."""
    if importlib.util.find_spec("ruff") is None:
        pytest.skip("ruff is not importable (it is in the test extra: pip install -e '.[test]')")
    command = [sys.executable, "-m", "ruff", "check", "--no-cache", *RUFF_PATHS]
    done = subprocess.run(
        command, cwd=REPO_ROOT, capture_output=True, text=True, timeout=300, check=False
    )
    report = done.stdout + done.stderr
    assert done.returncode == 0, f"ruff check failed (exit {done.returncode}):\n{report}"


def test_matplotlib_is_imported_only_under_viz():
    offenders = [
        f"{module}:{name} (line {line})"
        for module, tree in _modules()
        if not (module == "packlab.viz" or module.startswith("packlab.viz."))
        for name, line in _all_imports(tree, module)
        if name.split(".")[0] == "matplotlib"
    ]
    assert not offenders, "matplotlib imported outside packlab.viz:\n  " + "\n  ".join(offenders)


_UNTYPED_DICT = re.compile(r"^(typing\.)?[Dd]ict\[str, *(typing\.)?Any\]$")


def test_core_records_use_no_untyped_dicts():
    path = PACKAGE_DIR / "core" / "records.py"
    if not path.exists():
        pytest.skip("packlab/core/records.py does not exist yet")
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    offenders = []
    for node in ast.walk(tree):
        expression = None
        if isinstance(node, ast.Subscript):
            expression = ast.unparse(node)
        elif isinstance(node, ast.Constant) and isinstance(node.value, str):  # a quoted annotation
            expression = node.value.strip()
        if expression is not None and _UNTYPED_DICT.match(expression):
            offenders.append(f"line {node.lineno}: {expression}")
    assert not offenders, "dict[str, Any] in packlab/core/records.py:\n  " + "\n  ".join(offenders)
