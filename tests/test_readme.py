"""Every Python block of the README runs as written (with a small log the test makes at the name it uses)."""

from __future__ import annotations

import gzip
import re
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"


def python_blocks(text: str) -> list[str]:
    """The README's fenced ``python`` blocks, in order."""
    return re.findall(r"```python\n(.*?)```", text, flags=re.S)


def test_the_readme_has_python_blocks_and_few_lines():
    text = README.read_text(encoding="utf-8")
    assert len(python_blocks(text)) >= 3
    assert len(text.splitlines()) <= 250


def test_every_python_block_runs(rooms_log, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "robot-run.log.gz").write_bytes(gzip.compress(Path(rooms_log).read_bytes()))
    namespace: dict[str, object] = {"__name__": "readme"}
    for k, block in enumerate(python_blocks(README.read_text(encoding="utf-8"))):
        try:
            exec(compile(block, f"README.md block {k + 1}", "exec"), namespace)
        except Exception as err:
            pytest.fail(f"README block {k + 1} fails: {type(err).__name__}: {err}")
    out = capsys.readouterr().out
    assert "'top1'" in out and "places," in out and "vnnnnfnnnnbnnnvnncnnn" in out
    assert (tmp_path / "places.sqlite").exists()
