"""Fuzzing what is loaded: damaged database files, CARMEN logs cut at every block boundary, damaged images.

Each property holds for every example: a load either gives back what was
saved or raises the library's one-line error, never another exception and
never a different model. ``HYPOTHESIS_PROFILE=long`` runs 20 times as many
examples (docs/ROBUSTNESS.md).
"""

from __future__ import annotations

import gzip
import io
import itertools
import json
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fingerloc.errors import DatabaseError, DataFormatError, FingerlocError

from .conftest import fuzz_examples

_counter = itertools.count()


@pytest.fixture(scope="module")
def saved(tmp_path_factory):
    from fingerloc.io.jsonl import read_observations
    from fingerloc.pipeline.learning import learn_into

    d = tmp_path_factory.mktemp("fuzzdb")
    lines = []
    for k, lab in enumerate("abc"):
        for j in range(3):
            ve = [(10 + 37 * k + 40 * i + 2 * j) % 360 for i in range(5)]
            lines.append(json.dumps({"place": lab, "features": {"VE": ve, "c": [ve[0] + 5, ve[2] + 7]}}))
    (d / "t.jsonl").write_text("\n".join(lines) + "\n")
    obs = read_observations(d / "t.jsonl")
    db = d / "p.sqlite"
    learn_into(db, obs, preset="paper", calibrate=False)
    from fingerloc.pipeline.placemap import load_map

    lm = load_map(db)
    return _Saved(db.read_bytes(), obs, lm.labels, lm.model.predict_log_proba(obs), d)


class _Saved(tuple):  # type: ignore[type-arg]
    """The saved database and what it answers (a short repr: hypothesis prints it on a failure)."""

    def __new__(cls, *items):
        return super().__new__(cls, items)

    def __repr__(self) -> str:
        return "<saved database>"


@settings(max_examples=fuzz_examples(40), deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(flips=st.lists(st.tuples(st.integers(0, 10**9), st.integers(1, 255)), min_size=1, max_size=4))
def test_a_database_with_flipped_bytes_loads_the_same_or_is_refused(saved, flips):
    from fingerloc.pipeline.placemap import load_map

    data, obs, labels, logp, d = saved
    raw = bytearray(data)
    for at, x in flips:
        raw[at % len(raw)] ^= x
    path = d / f"f{next(_counter)}.sqlite"
    path.write_bytes(bytes(raw))
    try:
        lm = load_map(path)
    except DatabaseError as err:
        assert "\n" not in str(err)
        return
    assert lm.labels == labels
    np.testing.assert_allclose(lm.model.predict_log_proba(obs), logp, rtol=0, atol=1e-12)


def _reference(text: str) -> list[tuple[int, str, list[float]]]:
    """Laser records of a log, line by line (the reader's results without its blocks)."""
    from fingerloc.io.carmen import LaserRecord, parse_line

    out = []
    for k, line in enumerate(text.split("\n"), start=1):
        try:
            rec = parse_line(line, line=k)
        except DataFormatError:
            continue
        if isinstance(rec, LaserRecord):
            out.append((k, rec.message, rec.ranges.tolist()))
    return out


_LINE = st.one_of(
    st.just(""),
    st.just("# a comment"),
    st.just("PARAM robot_front_laser_max 30 nohost 0"),
    st.just("ODOM 1 2 0.5 0 0 0 1.0 host 1.0"),
    st.builds(lambda r, x: f"FLASER 3 {r:.2f} 1.5 2.0 {x:.1f} 0 0 0 0 0 1.0 h 1.0", st.floats(0.1, 9), st.floats(-9, 9)),
    st.builds(lambda r: f"  FLASER 3 {r:.2f} 1.5 2.0 0 0 0 0 0 0 1.0 h 1.0", st.floats(0.1, 9)),
    st.text(alphabet="ab LASER#\t", max_size=30),
)


@settings(max_examples=fuzz_examples(60), deadline=None)
@given(lines=st.lists(_LINE, min_size=1, max_size=40), block=st.integers(1, 200), gz=st.booleans(),
       end=st.sampled_from(["", "\n", "\n\n"]))  # fmt: skip
def test_the_block_reader_reads_every_line_as_the_line_reader(tmp_path_factory, lines, block, gz, end):
    import fingerloc.io.carmen as carmen

    text = "\n".join(lines) + end
    if not _reference(text):
        return
    d = tmp_path_factory.mktemp("log")
    path = d / ("x.log.gz" if gz else "x.log")
    path.write_bytes(gzip.compress(text.encode()) if gz else text.encode())
    saved, carmen._BLOCK = carmen._BLOCK, block  # every line cut across blocks somewhere
    try:
        _, records = carmen.read_log(path, skip_bad=True)
    except FingerlocError:
        pytest.fail("a log with laser lines refused")
    finally:
        carmen._BLOCK = saved
    got = [(r.line, r.message, r.ranges.tolist()) for r in records]
    assert got == _reference(text)


@pytest.fixture(scope="module")
def png_bytes():
    from PIL import Image

    rng = np.random.default_rng(2)
    buf = io.BytesIO()
    Image.fromarray((rng.random((24, 64, 3)) * 255).astype(np.uint8)).save(buf, format="PNG")
    return buf.getvalue()


@settings(max_examples=fuzz_examples(60), deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(cut=st.integers(0, 10**6), flips=st.lists(st.tuples(st.integers(0, 10**6), st.integers(1, 255)), max_size=3))
def test_a_damaged_png_is_read_whole_or_refused(tmp_path_factory, png_bytes, cut, flips):
    from fingerloc.io.images import open_image

    raw = bytearray(png_bytes[: max(8, len(png_bytes) - cut % len(png_bytes))])
    for at, x in flips:
        raw[at % len(raw)] ^= x
    path = Path(tmp_path_factory.mktemp("img")) / "x.png"
    path.write_bytes(bytes(raw))
    try:
        img = open_image(path)
    except DataFormatError as err:
        assert "\n" not in str(err)
        return
    assert img.dtype == np.uint8 and img.ndim == 3 and img.shape[2] == 3
