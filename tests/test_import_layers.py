"""Imports run one way: library packages never import the runner, the stages or the CLI.

Every module's imports are parsed with ``ast`` (function-level ones included), so a
violation fails here naming the offending ``file:line``, before any code runs.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PKG = ROOT / "r2s"

LIBRARIES = ("geometry", "graph", "sim", "geomopt", "physopt", "texture", "render", "metrics",
             "interaction", "diagnose", "io", "synth", "pictures", "viewer", "physical")
"""Library packages (docs/architecture.md): they may import each other and the low-level
modules (r2s.errors, r2s.console, r2s.scene_model), never what runs stages."""

RUNNER = ("r2s.runner", "r2s.pipeline", "r2s.batch", "r2s.stages", "r2s.cli", "r2s.cli_help",
          "r2s.cli_output", "r2s.api")

FORBIDDEN_EXTRA: dict[str, tuple[str, ...]] = {
    # io is the lowest library: it reads and writes files and knows no algorithm.
    "io": ("r2s.interaction", "r2s.diagnose", "r2s.physopt", "r2s.geomopt", "r2s.synth",
           "r2s.scene_model"),
}


def imported_modules(path: Path, root: Path = ROOT) -> list[tuple[int, str]]:
    """``(line, absolute module name)`` of every import statement in ``path`` (a module
    under ``root``/r2s)."""
    tree = ast.parse(path.read_text(), filename=str(path))
    package = ".".join(path.relative_to(root).with_suffix("").parts[:-1])
    out: list[tuple[int, str]] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out.extend((node.lineno, alias.name) for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - node.level + 1]
                module = ".".join(base + ([node.module] if node.module else []))
            else:
                module = node.module or ""
            out.append((node.lineno, module))
            # ``from r2s import pipeline`` imports the submodule r2s.pipeline
            out.extend((node.lineno, f"{module}.{alias.name}") for alias in node.names)
    return out


def _matches(module: str, prefixes: tuple[str, ...]) -> bool:
    return any(module == p or module.startswith(p + ".") for p in prefixes)


def violations(library: str, root: Path = ROOT) -> list[str]:
    forbidden = RUNNER + FORBIDDEN_EXTRA.get(library, ())
    found: dict[str, str] = {}  # one report per file:line, its first offending module
    for path in sorted((root / "r2s" / library).rglob("*.py")):
        for line, module in imported_modules(path, root):
            where = f"{path.relative_to(root)}:{line}"
            if _matches(module, forbidden) and where not in found:
                found[where] = f"{where} imports {module}"
    return list(found.values())


@pytest.mark.parametrize("library", LIBRARIES)
def test_library_never_imports_the_runner(library: str) -> None:
    assert (PKG / library).is_dir(), f"r2s/{library} is gone: update LIBRARIES"
    bad = violations(library)
    assert not bad, "imports against the layers:\n" + "\n".join(bad)


def test_the_checker_sees_function_level_and_relative_imports(tmp_path: Path) -> None:
    """The parser catches what the rule is about: an import hidden inside a function, and
    a relative one, are both reported with their line."""
    pkg = tmp_path / "r2s" / "io"
    pkg.mkdir(parents=True)
    probe = pkg / "probe.py"
    probe.write_text("import os\n\ndef f():\n    from r2s.runner.base import run_stage\n"
                     "    from ..stages import export\n    from . import paths\n")
    found = imported_modules(probe, tmp_path)
    bad = violations("io", tmp_path)
    assert (4, "r2s.runner.base") in found
    assert (5, "r2s.stages") in found and (5, "r2s.stages.export") in found
    assert (6, "r2s.io.paths") in found
    assert bad == ["r2s/io/probe.py:4 imports r2s.runner.base",
                   "r2s/io/probe.py:5 imports r2s.stages"]


def test_scene_model_is_below_the_runner() -> None:
    """The scene's model (hooks the stages apply) imports no runner or stage module."""
    path = PKG / "scene_model.py"
    bad = [f"{path.relative_to(ROOT)}:{line} imports {m}"
           for line, m in imported_modules(path) if _matches(m, RUNNER)]
    assert not bad, "\n".join(bad)
