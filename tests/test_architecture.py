"""The tree keeps its architecture: one-way imports, no math in the CLI, documented commands."""

import ast
from pathlib import Path

import pytest

from piezopress.piezocli.main import cli

ROOT = Path(__file__).resolve().parents[1]

# package (path prefix) -> module prefixes it must never import
FORBIDDEN = {
    "piezopress/analysis": ("piezopress.acquisition", "piezopress.pipelines", "piezopress.piezocli"),
    "piezopress/acquisition": ("piezopress.analysis", "piezopress.pipelines", "piezopress.piezocli"),
    "piezopress": ("piezopress.pipelines", "piezopress.piezocli"),
    "pipelines": ("piezopress.piezocli",),
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


def _all_commands():
    import click

    ctx = click.Context(cli)
    return {name: cli.get_command(ctx, name) for name in cli.list_commands(ctx)}


def test_every_command_has_help_with_an_example():
    commands = _all_commands()
    assert len(commands) >= 16
    for name, cmd in commands.items():
        assert cmd is not None, f"`piezopress {name}` is listed but its module defines no such command"
        assert cmd.help and "Example" in cmd.help, f"`piezopress {name}` lacks help text with an Example"


def test_the_command_table_lists_exactly_the_commands_the_modules_define():
    import importlib

    from piezopress.piezocli.main import COMMANDS

    for module in {m for m, _ in COMMANDS.values()}:
        importlib.import_module(f"piezopress.piezocli.{module}")
    assert set(cli.commands) == set(COMMANDS)  # every defined command is listed, and no listed one is missing
    for name, (module, short) in COMMANDS.items():
        assert cli.commands[name].callback.__module__ == f"piezopress.piezocli.{module}", name
        assert short.endswith(".") and len(short) <= 80, name


@pytest.mark.parametrize("args", [["--version"], ["--help"]])
def test_start_up_imports_no_heavy_library(args):
    """--version, --help and shell completion load no command module (issue 12: under 0.5 s)."""
    import subprocess
    import sys

    code = (
        "import sys; from piezopress.piezocli.main import cli\n"
        f"try:\n    cli.main({args!r}, standalone_mode=False)\nexcept SystemExit:\n    pass\n"
        "print(sorted(m for m in ('numpy', 'scipy', 'pandas', 'matplotlib', 'cvxpy', 'pyarrow') if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT).stdout
    assert out.strip().splitlines()[-1] == "[]", out
