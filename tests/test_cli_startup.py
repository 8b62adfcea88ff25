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


def test_help_imports_neither_numpy_nor_rich():
    # `fingerloc --help` and every command's --help, each in a fresh interpreter (what the console
    # script runs): the help text is click's, so nothing numeric and no rich console is needed
    from fingerloc.cli import app

    paths = _command_paths(typer.main.get_command(app))
    code = (
        "import sys\n"
        "from fingerloc.cli import main\n"
        "for args in ARGS:\n"
        "    try:\n        main([*args, '--help'])\n    except SystemExit as e:\n        assert e.code == 0, (args, e.code)\n"
        "print(','.join(m for m in ('numpy', 'rich.console', 'scipy', 'numba') if m in sys.modules), file=sys.stderr)\n"
    )
    for group in (paths[:1], paths):  # the root help alone, then all of them in one process
        res = subprocess.run(
            [sys.executable, "-c", f"ARGS = {group!r}\n" + code], capture_output=True, text=True, check=True
        )
        assert res.stdout.count("Usage: fingerloc") == len(group)
        assert res.stderr.strip() == "", f"imported by --help: {res.stderr.strip()}"


def test_help_kind_names_are_the_readers():
    # cli.features names the input kinds in its help without importing the readers (numpy)
    from fingerloc.cli import features
    from fingerloc.pipeline.files import KINDS

    assert features.KIND_NAMES == tuple(KINDS)
    assert features.KINDS is KINDS and features.FeatureOptions.__name__ == "FeatureOptions"


def test_lazy_console_and_lazy_names_work():
    from fingerloc._lazy import LazyAttr, LazyModule
    from fingerloc.cli.app import console, err_console, real_console

    m = LazyModule("json")
    assert m.dumps([1]) == "[1]" and "dumps" in vars(m)
    f = LazyAttr("json", "loads")
    assert f("[2]") == [2] and f.resolve() is __import__("json").loads
    from rich.console import Console

    assert isinstance(real_console(console), Console) and isinstance(real_console(err_console), Console)
    assert real_console(err_console).stderr and not real_console(console).stderr
    c = Console()
    assert real_console(c) is c
