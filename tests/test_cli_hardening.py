"""Every failure of the command line is one line ``error: ...`` and exit code 2."""

from __future__ import annotations

import json
import os
import stat

import pytest

from fingerloc.cli._io import check_output, strict_json, write_json
from fingerloc.errors import InvalidParameterError

from ._cli import run_cli as run


def _places_file(path, labels=("a", "b")):
    lines = []
    for k, lab in enumerate(labels):
        for j in range(3):
            ve = [(10 + 90 * k + 40 * i + 2 * j) % 360 for i in range(5)]
            lines.append(json.dumps({"place": lab, "features": {"VE": ve, "c": [ve[0] + 5, ve[2] + 7]}}))
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def _one_error_line(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("error: "), err
    return lines[0]


@pytest.mark.parametrize(
    "args",
    [
        ("learn", "--bogus"),
        ("learn",),
        ("localize", "x.jsonl", "--db", "x.sqlite", "--top", "many"),
        ("reproduce", "table1", "--trials", "1000000000000"),
        ("nosuchcommand",),
    ],
)
def test_usage_errors_are_one_line(capsys, args):
    code, _, err = run(capsys, *args)
    assert code == 2
    line = _one_error_line(err)
    assert not line.startswith("error: Error")


def test_trials_bound_names_the_flag(capsys):
    code, _, err = run(capsys, "reproduce", "table1", "--trials", "1000000000000")
    assert code == 2 and "--trials" in _one_error_line(err)


def test_non_utf8_argument(capsys):
    code, _, err = run(capsys, "fingerprint", "bad\udcff.jsonl")
    assert code == 2 and "UTF-8" in _one_error_line(err)


@pytest.mark.parametrize(
    ("line", "needle"),
    [
        ('{"features": {"VE": [' + "9" * 400 + "]}}", "400 digits"),
        ('{"features": {"VE": [' + "9" * 5000 + "]}}", "5000 digits"),
        ("[" * 100_000 + "]" * 100_000, "nested too deeply"),
        ('{"place": "\\ud800", "features": {}}', "surrogate"),
    ],
)
@pytest.mark.parametrize("command", ["fingerprint", "learn", "localize", "track"])
def test_hostile_json_lines(tmp_path, capsys, line, needle, command):
    data = tmp_path / "d.jsonl"
    data.write_text(line + "\n", encoding="utf-8")
    db = tmp_path / "p.sqlite"
    if command != "fingerprint":
        assert run(capsys, "learn", _places_file(tmp_path / "train.jsonl"), "--db", db)[0] == 0
    before = db.read_bytes() if db.exists() else None
    args = [command, data] + ([] if command == "fingerprint" else ["--db", db])
    code, _, err = run(capsys, *args)
    assert code == 2
    line1 = _one_error_line(err)
    assert needle in line1 and "d.jsonl:1" in line1
    if before is not None:
        assert db.read_bytes() == before


def test_markup_in_labels_is_printed_literally(tmp_path, capsys):
    data = _places_file(tmp_path / "d.jsonl", labels=("[/x]", "[red]b[/red]"))
    db = tmp_path / "[bold]p.sqlite"
    code, _, err = run(capsys, "learn", data, "--db", db)
    assert code == 0, err
    assert "[bold]p.sqlite" in err
    code, out, err = run(capsys, "places", "--db", db)
    assert code == 0, err
    assert "[/x]" in out and "[red]b[/red]" in out
    code, out, err = run(capsys, "localize", data, "--db", db)
    assert code == 0, err
    assert "[/x]" in out and "[red]b[/red]" in out


@pytest.mark.parametrize("where", ["missing", "directory", "readonly"])
def test_output_paths_checked_before_work(tmp_path, capsys, where):
    data = _places_file(tmp_path / "d.jsonl")
    db = tmp_path / "p.sqlite"
    assert run(capsys, "learn", data, "--db", db)[0] == 0
    if where == "missing":
        out = tmp_path / "nope" / "o.json"
    elif where == "directory":
        out = tmp_path / "adir"
        out.mkdir()
    else:
        ro = tmp_path / "ro"
        ro.mkdir()
        ro.chmod(0o500)
        out = ro / "o.json"
        if os.access(ro, os.W_OK):  # running as root: permissions do not bind
            pytest.skip("root ignores directory permissions")
    code, stdout, err = run(capsys, "localize", data, "--db", db, "--json", out)
    assert code == 2
    line = _one_error_line(err)
    assert "--json" in line
    assert stdout == ""  # nothing computed, nothing printed
    assert not list(tmp_path.glob("**/*.tmp"))


def test_check_output_directory_kind(tmp_path):
    f = tmp_path / "f"
    f.write_text("x")
    with pytest.raises(InvalidParameterError, match=r"--out: .* not a directory"):
        check_output(f, "--out", directory=True)
    check_output(tmp_path / "new", "--out", directory=True)


def test_strict_json_nulls_with_reason(tmp_path):
    clean, nulls = strict_json({"a": [1.0, float("nan")], "b": {"c": float("inf")}})
    assert clean == {"a": [1.0, None], "b": {"c": None}}
    assert set(nulls) == {"/a/1", "/b/c"} and "nan" in nulls["/a/1"]
    out = tmp_path / "o.json"
    write_json(out, {"x": float("-inf")})
    text = out.read_text()
    assert "Infinity" not in text
    js = json.loads(text)
    assert js["x"] is None and "/x" in js["nulls"]


def test_json_file_mode_follows_umask(tmp_path):
    old = os.umask(0o022)
    try:
        write_json(tmp_path / "o.json", {"a": 1})
    finally:
        os.umask(old)
    assert stat.S_IMODE((tmp_path / "o.json").stat().st_mode) == 0o644


def test_json_through_symlink_keeps_the_link(tmp_path):
    real = tmp_path / "real.json"
    real.write_text("{}")
    link = tmp_path / "link.json"
    link.symlink_to(real)
    write_json(link, {"a": 2})
    assert link.is_symlink() and json.loads(real.read_text()) == {"a": 2}


def _png_header(path, w, h):
    """A PNG that declares ``w`` x ``h`` pixels in a few bytes (the pixel data is not needed to refuse it)."""
    import struct
    import zlib

    def chunk(t, d):
        return struct.pack(">I", len(d)) + t + d + struct.pack(">I", zlib.crc32(t + d) & 0xFFFFFFFF)

    ihdr = struct.pack(">IIBBBBB", w, h, 8, 0, 0, 0, 0)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"\0" * 8)) + chunk(b"IEND", b""))
    return path


@pytest.mark.parametrize("side", [20000, 13000])
def test_image_pixel_limit(tmp_path, capsys, side):
    png = _png_header(tmp_path / "big.png", side, side)
    code, _, err = run(capsys, "features", png)
    assert code == 2 and "--max-pixels" in _one_error_line(err) and f"{side}x{side}" in err


def test_image_pixel_limit_can_be_raised(tmp_path):
    from fingerloc.errors import DataFormatError
    from fingerloc.io.images import open_image

    png = tmp_path / "small.png"
    from PIL import Image

    Image.new("RGB", (40, 30), (10, 200, 30)).save(png)
    with pytest.raises(DataFormatError, match="1,200 pixels"):
        open_image(png, max_pixels=1000)
    assert open_image(png, max_pixels=1200).shape == (30, 40, 3)


@pytest.mark.parametrize(
    ("name", "content", "needle"),
    [
        ("r.log", bytes(range(256)) * 20, "binary data"),
        ("r.log.gz", bytes(range(256)) * 20, "not gzip"),
        ("e.log", b"", "empty file"),
        ("n.log", b"ODOM 1 2 3 0 0 0 1 host 1\n# a comment\n", "no laser scan"),
    ],
)
def test_features_on_a_non_sensor_file(tmp_path, capsys, name, content, needle):
    f = tmp_path / name
    f.write_bytes(content)
    code, _, err = run(capsys, "features", f)
    assert code == 2 and needle in _one_error_line(err) and name in err


@pytest.mark.parametrize(
    "args",
    [
        ("features", "x.png", "--kind", "omni", "--center", "1", "1", "--radii", "10", "inf"),
        ("fingerprint", "x.jsonl", "--empty-step-deg", "1e-9"),
        ("track", "x.jsonl", "--db", "p.sqlite", "--filter", "pose", "--seed", "-1"),
        ("learn", "x.jsonl", "--db", "p.sqlite", "-k", "0"),
    ],
)
def test_option_ranges(capsys, args):
    code, _, err = run(capsys, *args)
    flag = next(a for a in args if a.startswith("-") and a not in ("--db", "--kind", "--center", "--filter"))
    assert code == 2 and flag in _one_error_line(err)


def test_fingerprint_bound_in_the_library():
    from fingerloc.fingerprint import make_fingerprint
    from fingerloc.observation import Observation

    obs = Observation.from_degrees({"VE": [10.0]})
    with pytest.raises(InvalidParameterError, match="empty_step_deg"):
        make_fingerprint(obs, empty_step_deg=1e-9)
    assert make_fingerprint(obs, empty_step_deg=0.1).letters.count("n") == 3600  # 360 deg / 0.1 deg
