"""``fingerloc features`` on CARMEN logs (the ``carmen`` kind)."""

import gzip

import numpy as np

from fingerloc.io.carmen import flaser_bearings
from fingerloc.io.jsonl import read_observations

from ._cli import run_cli as run


def room_ranges(n=181, w=6.0, h=4.0, px=3.0, py=1.0):
    """Ranges of a 180 deg scan looking along +x from (px, py) in the box [0, w] x [0, h]: two corners ahead."""
    a = flaser_bearings(n)
    c, s = np.cos(a), np.sin(a)
    with np.errstate(divide="ignore", invalid="ignore"):
        tx = np.where(c > 1e-12, (w - px) / c, np.inf)
        ty = np.where(s > 1e-12, (h - py) / s, np.where(s < -1e-12, -py / s, np.inf))
    return np.minimum(tx, ty)


def flaser_line(k, ranges):
    r = " ".join(f"{v:.3f}" for v in ranges)
    return f"FLASER {len(ranges)} {r} {k * 0.1:.2f} 0.0 0.0 0 0 0 {k}.0 host {k}.0"


def write_log(path, lines, gz=False):
    text = "\n".join(lines) + "\n"
    if gz:
        with gzip.open(path, "wt") as fh:
            fh.write(text)
    else:
        path.write_text(text)
    return path


def test_features_on_carmen_log(tmp_path, capsys):
    lines = ["# a tiny log", "PARAM robot_front_laser_max 50 nohost 0"]
    lines += [flaser_line(k, room_ranges()) for k in range(3)]
    p = write_log(tmp_path / "tiny.log.gz", lines, gz=True)
    out = tmp_path / "o.jsonl"
    code, text, err = run(capsys, "features", p, "--place", "lab", "--json", out)
    assert code == 0, err
    rows = text.strip().splitlines()
    assert len(rows) == 3  # one line per scan
    assert rows[0].startswith("tiny.log.gz:3 FLASER [lab]  c(2): ")
    assert "| Ex(" in rows[0] and "| B(0): -" in rows[0]
    obs = read_observations(out)
    assert len(obs) == 3 and all(o.label == "lab" for o in obs)
    # the two corners of the box ahead: (6, 4) and (6, 0) seen from (3, 1)
    want = np.sort(np.degrees(np.arctan2([3.0, -1.0], [3.0, 3.0])))
    got = np.sort(np.degrees(np.angle(np.exp(1j * obs[0].c))))
    assert got.size == 2 and np.allclose(got, want, atol=1.5)
    assert obs[0].pose is not None and not obs[0].full_fov


def test_kind_explicit_and_skip_bad(tmp_path, capsys):
    lines = [flaser_line(0, room_ranges()), "FLASER 3 1 2", flaser_line(1, room_ranges())]
    p = write_log(tmp_path / "scans.txt", lines)  # an unknown extension: --kind needed
    code, _, err = run(capsys, "features", p, "--kind", "carmen")
    assert code == 2 and "scans.txt:2" in err and err.startswith("error:")
    code, text, err = run(capsys, "features", p, "--kind", "carmen", "--skip-bad")
    assert code == 0 and len(text.strip().splitlines()) == 2
    assert "skipped 1 malformed line" in err


def test_unknown_kind_lists_the_laser_kinds(tmp_path, capsys):
    p = write_log(tmp_path / "a.log", [flaser_line(0, room_ranges())])
    code, _, err = run(capsys, "features", p, "--kind", "lidar")
    assert code == 2 and "carmen" in err and "bag" in err
