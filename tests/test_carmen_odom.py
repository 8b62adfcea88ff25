"""The quick check of ``ODOM`` lines in ``read_log`` agrees with the full parser, line for line."""

import gzip

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fingerloc.errors import DataFormatError
from fingerloc.io.carmen import OdomRecord, _odom_valid, parse_line, read_log

_TOKENS = st.sampled_from(["0", "1.5", "-2e3", "nan", "inf", "-inf", "1e10", "-1e9", "x", "1,5", "", "ODOM", "0x1"])


@settings(max_examples=400, deadline=None)
@given(st.lists(_TOKENS, min_size=0, max_size=11), st.sampled_from(["ODOM", "ODOMETRY", "FLASER"]))
def test_odom_check_agrees_with_the_parser(tokens, head):
    text = " ".join([head, *tokens])
    try:
        parsed = isinstance(parse_line(text), OdomRecord)
    except DataFormatError:
        parsed = False
    assert _odom_valid(text) == parsed


def _log(tmp_path, odom_line):
    p = tmp_path / "run.log.gz"
    laser = "FLASER 3 1.0 2.0 3.0 0.0 0.0 0.0 0.0 0.0 0.0 5.0 host 5.0"
    with gzip.open(p, "wt") as f:
        f.write(f"{laser}\n{odom_line}\n{laser}\n")
    return p


def test_read_log_counts_odometry_and_refuses_a_bad_odom_line(tmp_path):
    info, recs = read_log(_log(tmp_path, "ODOM 1.0 2.0 0.1 0.0 0.0 0.0 6.0 host 6.0"))
    assert info.counts["ODOM"] == 1 and len(recs) == 2
    with pytest.raises(DataFormatError, match=r"run.log.gz:2: ODOM pose must be finite"):
        read_log(_log(tmp_path, "ODOM nan 2.0 0.1 0.0 0.0 0.0 6.0 host 6.0"))
    with pytest.raises(DataFormatError, match=r"run.log.gz:2: ODOM line has 9 fields"):
        read_log(_log(tmp_path, "ODOM 1.0 2.0 0.1 0.0 0.0 6.0 host 6.0"))
