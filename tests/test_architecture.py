"""The tree keeps its architecture: one-way imports, no math in the CLI, documented commands."""

import ast
from pathlib import Path

import pytest

from piezocli.main import cli

ROOT = Path(__file__).resolve().parents[1]

# package (path prefix) -> module prefixes it must never import
FORBIDDEN = {
    "piezopress/analysis": ("piezopress.acquisition", "pipelines", "piezocli"),
    "piezopress/acquisition": ("piezopress.analysis", "pipelines", "piezocli"),
    "piezopress": ("pipelines", "piezocli"),
    "pipelines": ("piezocli",),
    "piezocli": ("numpy", "scipy", "cvxpy", "control"),  # the CLI parses and prints; no math
}


def imports_of(path: Path):
    tree = ast.parse(path.read_text(encoding="utf-8"))
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            yield from (a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            yield node.module


@pytest.mark.parametrize("package", list(FORBIDDEN))
def test_imports_go_one_way(package):
    bad = []
    for path in (ROOT / package).rglob("*.py"):
        for mod in imports_of(path):
            if any(mod == f or mod.startswith(f + ".") for f in FORBIDDEN[package]):
                bad.append(f"{path.relative_to(ROOT)} imports {mod}")
    assert not bad, "\n".join(bad)


def test_every_command_has_help_with_an_example():
    for name, cmd in cli.commands.items():
        assert cmd.help and "Example" in cmd.help, f"`piezopress {name}` lacks help text with an Example"
