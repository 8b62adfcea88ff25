"""Start-up of the ``fingerloc`` command: what it imports, ``--version`` and every command's ``--help``."""

from __future__ import annotations

import subprocess
import sys
from typing import Any

import typer.main
from typer.testing import CliRunner

from fingerloc._version import __version__
from tests._cli import run_cli

HEAVY = ("numba", "matplotlib", "scipy", "rosbags")


def test_building_the_cli_does_not_import_heavy_packages():
    # A fresh interpreter: import the package, build the whole command tree (every command module
    # registers itself and typer resolves every signature), then look at what got imported.
    code = (
        "import sys, typer.main, fingerloc.cli\n"
        "from fingerloc.cli import app\n"
        "typer.main.get_command(app)\n"
        f"print(','.join(m for m in {HEAVY!r} if m in sys.modules))\n"
    )
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert res.stdout.strip() == "", f"imported at start-up: {res.stdout.strip()}"


def test_version_fast_path_imports_nothing_heavy():
    code = (
        "import sys\n"
        "from fingerloc.cli import main\n"
        "try:\n    main(['--version'])\nexcept SystemExit as e:\n    assert e.code == 0\n"
        "print(','.join(m for m in ('numpy', 'typer', 'rich') if m in sys.modules), file=sys.stderr)\n"
    )
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert res.stdout == f"fingerloc {__version__}\n"
    assert res.stderr.strip() == ""


def test_version_same_from_typer_and_fast_path(capsys):
    code, out, _ = run_cli(capsys, "--version")
    assert code == 0 and out == f"fingerloc {__version__}\n"
    from fingerloc.cli import app

    res = CliRunner().invoke(app, ["--version"])
    assert res.exit_code == 0 and res.output == out


def _command_paths(cmd: Any, prefix: tuple[str, ...] = ()) -> list[tuple[str, ...]]:
    paths = [prefix]
    if hasattr(cmd, "commands"):  # a group (typer may vendor its own click)
        for name, sub in cmd.commands.items():
            paths += _command_paths(sub, (*prefix, name))
    return paths


def test_every_command_help_works(capsys):
    from fingerloc.cli import app

    paths = _command_paths(typer.main.get_command(app))
    assert ("learn",) in paths and ("bench", "speed") in paths and ("reproduce", "table1") in paths
    for path in paths:
        code, out, err = run_cli(capsys, *path, "--help")
        assert code == 0, (path, err)
        assert out.startswith("Usage: fingerloc") and " ".join(path) in out.splitlines()[0], path
