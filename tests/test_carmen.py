import gzip
import math

import numpy as np
import pytest

from fingerloc.errors import DataFormatError, InvalidParameterError
from fingerloc.io.carmen import (
    LaserRecord,
    OdomRecord,
    ReadStats,
    detect_max_range,
    flaser_bearings,
    inspect_log,
    is_carmen_path,
    iter_records,
    iter_scans,
    parse_line,
    read_scans,
)


def flaser(ranges, pose=(1.0, 2.0, 0.5), msg="FLASER", ts=12.5):
    r = " ".join(str(v) for v in ranges)
    x, y, t = pose
    return f"{msg} {len(ranges)} {r} {x} {y} {t} {x + 0.1} {y} {t} {ts} host {ts + 0.01}"


def robotlaser(ranges, remissions=None, *, max_range=81.91, msg="ROBOTLASER1"):
    n = len(ranges)
    rem = remissions or []
    res = math.pi / (n - 1)
    head = f"{msg} 0 {-math.pi / 2} {math.pi} {res} {max_range} 0.01 0"
    body = f"{n} {' '.join(map(str, ranges))} {len(rem)} {' '.join(map(str, rem))}".replace("  ", " ")
    tail = "1.2 2.0 0.0 1.0 2.0 0.0 0.3 0.1 0.5 0.2 0.0 33.5 host 33.6"
    return f"{head} {body} {tail}"


ODOM = "ODOM 0.5 0.25 0.1 0.3 0.05 0 7.5 pippo 7.5"

HEADER = [
    "# message formats defined: PARAM SYNC ODOM FLASER RLASER",
    "PARAM robot_front_laser_max 50 nohost 0",
    "NEFF 30",
    "",
]


def write_log(tmp_path, lines, name="x.log", gz=False):
    p = tmp_path / name
    text = "\n".join(lines) + "\n"
    if gz:
        with gzip.open(p, "wt", encoding="utf-8") as fh:
            fh.write(text)
    else:
        p.write_text(text, encoding="utf-8")
    return p


# ---- bearings ---------------------------------------------------------------------------------------


def test_bearings_odd_includes_both_ends():
    b = np.degrees(flaser_bearings(181))
    assert b[0] == pytest.approx(-90) and b[-1] == pytest.approx(90)
    assert np.allclose(np.diff(b), 1.0)
    b = np.degrees(flaser_bearings(361))
    assert b[-1] == pytest.approx(90) and np.allclose(np.diff(b), 0.5)


def test_bearings_even_step_180_over_n():
    b = np.degrees(flaser_bearings(180))
    assert b[0] == pytest.approx(-90) and b[-1] == pytest.approx(89)
    b = np.degrees(flaser_bearings(360))
    assert np.allclose(np.diff(b), 0.5) and b[-1] == pytest.approx(89.5)


def test_rear_bearings_turned_half_a_turn():
    b = np.degrees(flaser_bearings(181, rear=True))
    assert b[0] == pytest.approx(90) and b[-1] == pytest.approx(270)


def test_bearings_need_two_beams():
    with pytest.raises(InvalidParameterError):
        flaser_bearings(1)


# ---- parse_line of every message type ------------------------------------------------------------


def test_parse_flaser():
    rec = parse_line(flaser([1.0, 2.0, 3.0, 4.0, 5.0]), line=7)
    assert isinstance(rec, LaserRecord)
    assert rec.message == "FLASER" and rec.line == 7
    assert np.allclose(rec.ranges, [1, 2, 3, 4, 5])
    assert np.allclose(np.degrees(rec.bearings), [-90, -45, 0, 45, 90])
    assert rec.pose == (1.0, 2.0, 0.5)
    assert rec.odom == pytest.approx((1.1, 2.0, 0.5))
    assert rec.timestamp == 12.5
    assert rec.intensities is None


def test_parse_rlaser():
    rec = parse_line(flaser([1.0, 2.0, 3.0], msg="RLASER"))
    assert isinstance(rec, LaserRecord) and rec.message == "RLASER"
    assert np.allclose(np.degrees(rec.bearings), [90, 180, 270])


def test_parse_robotlaser_with_remissions():
    rec = parse_line(robotlaser([1.0, 2.0, 3.0], [100, 5000, 20]))
    assert isinstance(rec, LaserRecord) and rec.message == "ROBOTLASER1"
    assert np.allclose(np.degrees(rec.bearings), [-90, 0, 90])
    assert np.allclose(rec.intensities, [100, 5000, 20])
    assert rec.max_range == pytest.approx(81.91)
    assert rec.pose == (1.0, 2.0, 0.0)
    assert rec.sensor_offset == pytest.approx((0.2, 0.0, 0.0))
    assert rec.timestamp == pytest.approx(33.5)


def test_parse_robotlaser_without_remissions():
    rec = parse_line(robotlaser([1.0, 2.0, 3.0]))
    assert isinstance(rec, LaserRecord) and rec.intensities is None


def test_robotlaser_offset_in_robot_frame():
    line = robotlaser([1.0, 2.0, 3.0]).replace(
        "1.2 2.0 0.0 1.0 2.0 0.0", f"1.0 2.3 {math.pi / 2} 1.0 2.0 {math.pi / 2}"
    )
    rec = parse_line(line)
    assert isinstance(rec, LaserRecord)
    assert rec.sensor_offset == pytest.approx((0.3, 0.0, 0.0), abs=1e-12)


def test_parse_odom():
    rec = parse_line(ODOM, line=3)
    assert isinstance(rec, OdomRecord)
    assert rec.pose == (0.5, 0.25, 0.1)
    assert (rec.tv, rec.rv, rec.accel, rec.timestamp, rec.line) == (0.3, 0.05, 0.0, 7.5, 3)


@pytest.mark.parametrize("line", ["", "   ", "# comment", "PARAM a b c 0", "NEFF 30", "SYNC x", "TRUEPOS 1 2 3"])
def test_other_lines_are_skipped(line):
    assert parse_line(line) is None


@pytest.mark.parametrize(
    ("line", "match"),
    [
        ("FLASER", "no beam count"),
        ("FLASER x 1 2", "beam count must be an integer"),
        ("FLASER 3 1 2 3 0 0 0 0 0 0 1 h", "fields, expected"),
        (flaser([1.0, 2.0, 3.0]).replace(" 2.0 ", " abc ", 1), "readings must be numbers, got 'abc'"),
        (flaser([1.0, -2.0, 3.0]), "must be >= 0"),
        (flaser([1.0]), "at least 2 beams"),
        (flaser([1.0, 2.0]).replace("1.0 2.0 0.5", "1.0 nan 0.5", 1), "pose must be finite"),
        ("ODOM 1 2 3", "fields, expected"),
        ("ODOM a 0 0 0 0 0 1 h 1", "must be a number"),
        ("ROBOTLASER1 0 0 3.14", "too few"),
        (robotlaser([1.0, 2.0, 3.0], [1, 2, 3]).rsplit(" ", 2)[0], "fields, expected"),
    ],
)
def test_malformed_lines(line, match):
    with pytest.raises(DataFormatError, match=match):
        parse_line(line)


# ---- files ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("gz", [False, True])
def test_read_plain_and_gzip(tmp_path, gz):
    lines = [
        *HEADER,
        ODOM,
        flaser([1.0, 2.0, 50.0]),
        flaser([1.5, 2.5, 3.5], msg="RLASER"),
        robotlaser([1.0, 2.0, 3.0], [10, 20, 30]),
    ]
    p = write_log(tmp_path, lines, name="x.log.gz" if gz else "x.log", gz=gz)
    recs = list(iter_records(p))
    assert [type(r).__name__ for r in recs] == ["OdomRecord", "LaserRecord", "LaserRecord", "LaserRecord"]
    st = ReadStats()
    scans = list(iter_scans(p, stats=st))
    assert len(scans) == 3 and st.scans == 3 and st.skipped == 0 and st.lines == len(lines)
    f, r, rl = scans
    # FLASER max range from PARAM (no repeated saturation value in so small a log): 50 m -> no return
    assert f.max_range == 50.0
    assert np.isinf(f.ranges[2]) and np.allclose(f.ranges[:2], [1, 2])
    assert f.pose == (1.0, 2.0, 0.5) and f.timestamp == 12.5
    assert np.allclose(np.degrees(r.bearings), [90, 180, 270])
    assert np.allclose(rl.intensities, [10, 20, 30])
    assert rl.max_range == pytest.approx(81.91)


def test_messages_filter(tmp_path):
    p = write_log(tmp_path, [flaser([1.0, 2.0, 3.0]), flaser([1.0, 2.0, 3.0], msg="RLASER")])
    assert len(read_scans(p, messages=["FLASER"])) == 1
    with pytest.raises(InvalidParameterError, match="LASER9"):
        read_scans(p, messages=["LASER9"])


def test_gzip_detected_by_content_not_name(tmp_path):
    p = write_log(tmp_path, [flaser([1.0, 2.0, 3.0])], name="plain-name.log", gz=True)
    assert len(read_scans(p)) == 1


def test_malformed_line_names_path_and_line(tmp_path):
    lines = [*HEADER, flaser([1.0, 2.0, 3.0]), "FLASER 3 1 2 oops 0 0 0 0 0 0 1 h 1", flaser([1.0, 2.0, 3.0])]
    p = write_log(tmp_path, lines)
    with pytest.raises(DataFormatError) as info:
        read_scans(p)
    assert info.value.line == 6 and info.value.path == str(p)
    assert f"{p}:6:" in str(info.value) and "'oops'" in str(info.value)


def test_skip_bad_counts(tmp_path):
    lines = [
        flaser([1.0, 2.0, 3.0]),
        "FLASER 3 1 2",
        flaser([1.0, 2.0, 3.0]),
        "ODOM 1 2",
        flaser([1.0, -2.0, 3.0]),
    ]
    p = write_log(tmp_path, lines, gz=True)
    st = ReadStats()
    scans = list(iter_scans(p, skip_bad=True, stats=st))
    assert len(scans) == 2 and st.skipped == 3
    assert st.first_errors[0].startswith(f"{p}:2:")


def test_truncated_gzip_is_a_data_format_error(tmp_path):
    p = write_log(tmp_path, [flaser([1.0, 2.0, 3.0])] * 200, gz=True)
    data = p.read_bytes()
    p.write_bytes(data[: len(data) // 2])
    with pytest.raises(DataFormatError, match="corrupt or truncated"):
        read_scans(p, max_range=80.0)


def test_missing_file(tmp_path):
    with pytest.raises(DataFormatError, match="no such file"):
        read_scans(tmp_path / "nope.log")


# ---- no return / max range -----------------------------------------------------------------------


@pytest.mark.parametrize("code", [50.0, 51.2, 80.0, 81.83, 81.91, 32.76])
def test_max_range_detected_from_repeats(tmp_path, code):
    lines = [flaser([1.0, code, code, 3.0, 25.0]), flaser([code, 2.0, 4.0, 6.0, 12.0])]
    p = write_log(tmp_path, lines)
    assert detect_max_range(p) == pytest.approx(code)
    scans = read_scans(p)
    assert np.isinf(scans[0].ranges[1:3]).all() and np.isinf(scans[1].ranges[0])
    assert scans[0].ranges[4] == 25.0 and scans[0].max_range == pytest.approx(code)


def test_two_codes_near_the_top(tmp_path):
    # Freiburg 101 mixes 81.83 (a few) and 81.91 (many): both are no return.
    lines = [flaser([81.91, 81.91, 81.83, 1.0]), flaser([81.91, 81.83, 81.83, 2.0])]
    p = write_log(tmp_path, lines)
    assert detect_max_range(p) == pytest.approx(81.83)
    assert np.isinf(read_scans(p)[0].ranges[:3]).all()


def test_rare_long_reading_is_kept(tmp_path):
    # 49.71 m occurs a few times below a 50 m code: a reading, not a second code.
    lines = [flaser([50.0, 50.0, 50.0, 49.71, 49.71, 49.71, 1.0])]
    p = write_log(tmp_path, lines)
    assert detect_max_range(p) == 50.0
    s = read_scans(p)[0]
    assert np.isinf(s.ranges[:3]).all() and np.allclose(s.ranges[3:6], 49.71)


def test_known_code_without_repeats(tmp_path):
    p = write_log(tmp_path, [flaser([1.0, 81.83, 2.0])])
    assert detect_max_range(p) == pytest.approx(81.83)


def test_no_marker_keeps_every_reading(tmp_path):
    p = write_log(tmp_path, [flaser([1.0, 7.5, 2.0])])
    assert detect_max_range(p) is None
    s = read_scans(p)[0]
    assert np.isfinite(s.ranges).all() and s.max_range > 7.5


def test_robotlaser_field_used_when_no_repeats(tmp_path):
    p = write_log(tmp_path, [robotlaser([1.0, 7.9, 8.0], max_range=8.0)])
    info = inspect_log(p)
    assert info.max_range["ROBOTLASER1"] == 8.0
    s = read_scans(p)[0]
    assert np.isinf(s.ranges[2]) and s.ranges[1] == 7.9


def test_explicit_max_range_overrides(tmp_path):
    p = write_log(tmp_path, [flaser([1.0, 50.0, 50.0, 50.0, 30.0])])
    s = read_scans(p, max_range=20.0)[0]
    assert np.isinf(s.ranges[1:]).all() and s.ranges[0] == 1.0
    with pytest.raises(InvalidParameterError, match="max_range"):
        read_scans(p, max_range=-1.0)


def test_inspect_log_counts_and_params(tmp_path):
    p = write_log(tmp_path, [*HEADER, ODOM, ODOM, flaser([1.0, 2.0, 3.0])])
    info = inspect_log(p)
    assert info.counts == {"ODOM": 2, "FLASER": 1}
    assert info.params["robot_front_laser_max"] == "50"


def test_streaming_does_not_read_ahead(tmp_path):
    # The generator yields the first scan before it meets a malformed line further on.
    p = write_log(tmp_path, [flaser([1.0, 2.0, 3.0]), "FLASER bad"])
    it = iter_scans(p, max_range=80.0)
    first = next(it)
    assert first.ranges.size == 3
    with pytest.raises(DataFormatError, match=":2:"):
        next(it)


def test_is_carmen_path():
    for name in ["a.log", "b.log.gz", "c.gz", "d.clf", "E.LOG"]:
        assert is_carmen_path(name)
    for name in ["a.bag", "b.db3", "c.mcap", "d.jsonl"]:
        assert not is_carmen_path(name)


def test_iter_laser_gives_line_numbers_and_default_messages(tmp_path):
    from fingerloc.io.carmen import default_messages, iter_laser

    p = write_log(tmp_path, [*HEADER, flaser([1.0, 2.0, 3.0]), robotlaser([1.0, 2.0, 3.0])])
    got = [(rec.message, rec.line) for rec, _ in iter_laser(p)]
    assert got == [("FLASER", 5), ("ROBOTLASER1", 6)]
    assert default_messages(inspect_log(p)) == ("FLASER",)
    p2 = write_log(tmp_path, [robotlaser([1.0, 2.0, 3.0])], name="r.log")
    assert default_messages(inspect_log(p2)) == ("ROBOTLASER1",)


def test_streaming_memory_stays_flat(tmp_path):
    # 600 scans of 361 beams: reading them one by one must not hold the log.
    import tracemalloc

    rng = np.random.default_rng(0)
    p = tmp_path / "big.log.gz"
    with gzip.open(p, "wt", encoding="utf-8", compresslevel=1) as fh:
        row = " ".join(f"{v:.2f}" for v in rng.uniform(0.5, 20, 361))
        for k in range(600):
            fh.write(f"FLASER 361 {row} {k * 0.01} 0 0 0 0 0 {k} h {k}\nODOM 0 0 0 0 0 0 {k} h {k}\n")
    tracemalloc.start()
    n = 0
    for s in iter_scans(p):
        n += s.ranges.size
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    assert n == 600 * 361
    assert peak < 1_500_000  # bytes (about 0.3 MB measured); the scans as a list take about 4 MB
