import json
import subprocess
import sys

import pytest

from ._cli import run_cli as run


def test_version_and_help(capsys):
    code, out, _ = run(capsys, "--version")
    assert code == 0 and out.startswith("fingerloc ")
    code, out, _ = run(capsys, "--help")
    assert code == 0 and "fingerprint" in out


def test_fingerprint_command(tmp_path, capsys):
    p = tmp_path / "d.jsonl"
    p.write_text(
        json.dumps(
            {
                "place": "a",
                "features": {
                    "VE": [10, 101, 250],
                    "c": [99, 300],
                    "CP": [{"bearing": 45, "hue": 130}],
                    "B": [180],
                    "Ex": [200],
                },
            }
        )
        + "\n"
        + json.dumps({"fov": [[-90, 90]], "features": {"c": [-60, 10, 45]}})
        + "\n"
    )
    code, out, _ = run(capsys, "fingerprint", str(p))
    assert code == 0
    assert out.splitlines() == ["vnFnnfnnnnbnnnvnncnnn", "cncnnncnnn"]
    code, out, _ = run(capsys, "fingerprint", str(p), "--json")
    recs = [json.loads(x) for x in out.splitlines()]
    assert recs[0]["place"] == "a" and recs[0]["fingerprint"] == "vnFnnfnnnnbnnnvnncnnn"
    assert len(recs[0]["bearings_deg"]) == len(recs[0]["fingerprint"])
    assert recs[1]["place"] is None


@pytest.mark.parametrize(
    ("content", "needle"),
    [
        ('{"features": {"VE": [1]}}\n{"features": {"VE": ["x"]}}\n', "d.jsonl:2"),
        ("", "empty"),
        ('{"features": {"Q": [1]}}\n', "'Q'"),
    ],
)
def test_bad_input_one_line_exit_2(tmp_path, content, needle):
    p = tmp_path / "d.jsonl"
    p.write_text(content)
    proc = subprocess.run(
        [sys.executable, "-c", "from fingerloc.cli import main; main()", "fingerprint", str(p)],
        capture_output=True,
        text=True,
    )
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and needle in lines[0]
    assert "Traceback" not in proc.stderr
