"""Two visits of the simulated offices: what changes between the training and the test visit."""

import numpy as np
import pytest

from fingerloc.errors import FingerlocError, InvalidParameterError
from fingerloc.sim import OFFICE_DAY, PARTS, SessionChange, make_office_sessions, make_offices, render_panorama

NOTHING = SessionChange(
    chair_moved=0.0,
    door_closed=0.0,
    leaf_swing_deg=0.0,
    seated_person=0.0,
    standing_person=0.0,
    lamp_switched=0.0,
    new_sun=False,
    window_emission=(1.3, 1.3),
)
EVERYTHING = SessionChange(chair_moved=1.0, door_closed=1.0, seated_person=1.0, standing_person=1.0, lamp_switched=1.0)


def _same(a, b):
    return all(
        np.array_equal(getattr(a, k), getattr(b, k), equal_nan=True)
        for k in ("segments", "z_range", "material", "decal_z", "part", "sun")
    ) and repr(a.materials) == repr(b.materials)


def test_training_visit_is_make_offices():
    pairs = make_office_sessions(4, similarity=0.8, random_state=3, world="paper", change_random_state=1)
    plain = make_offices(4, similarity=0.8, random_state=3, world="paper")
    assert all(_same(tr, w) for (tr, _), w in zip(pairs, plain, strict=True))
    # the test visit keeps the measurement point and the name, and differs somewhere
    assert all(te.anchor == tr.anchor and te.name == tr.name for tr, te in pairs)
    assert not all(_same(tr, te) for tr, te in pairs)
    # no change: the very same world
    assert all(tr is te for tr, te in make_office_sessions(2, random_state=3, world="paper", change=None))


def test_nothing_changed_gives_the_same_office():
    for tr, te in make_office_sessions(3, similarity=0.8, random_state=5, world="paper", change=NOTHING):
        assert _same(tr, te)


def test_every_change_happens_when_certain():
    person, leaf = PARTS.index("person"), PARTS.index("door_leaf")
    pairs = make_office_sessions(4, similarity=0.8, random_state=7, world="paper", change=EVERYTHING, change_random_state=2)
    for tr, te in pairs:
        assert (te.part == person).sum() >= 8  # someone seated (two boxes) or standing (three)
        assert not (tr.part == person).any()
        # every door is closed: a leaf segment lies along each doorway (door leaves were open or absent before)
        assert (te.part == leaf).sum() >= 1
        # no lamp stays on: the ceiling light boxes are gone (they sit at the ceiling height)
        assert not np.isclose(te.sun[:, 2], te.height).any()
        assert np.isclose(tr.sun[:, 2], tr.height).any()
        win = [m.emission for m in te.materials if m.emission > 0]
        assert win and all(0.8 <= e <= 2.0 for e in win)
        # the panorama at the measurement point changes
        pose = (*tr.anchor, 0.0)
        a = render_panorama(tr, pose, lighting=0.0, noise=0.0, width=180, height=40)
        b = render_panorama(te, pose, lighting=0.0, noise=0.0, width=180, height=40)
        assert np.abs(a.image - b.image).mean() > 0.005


def test_people_and_moved_chairs_keep_clear_of_the_measurement_point():
    new_parts = {PARTS.index("person"), PARTS.index("chair")}
    k = OFFICE_DAY.keep_clear_m
    seen = 0
    for seed in range(4):
        pairs = make_office_sessions(6, similarity=0.8, random_state=seed, world="paper", change=EVERYTHING)
        for tr, te in pairs:
            old = {tuple(s) for s in tr.segments}
            ax, ay = te.anchor
            for s, part in zip(te.segments, te.part, strict=True):
                if int(part) in new_parts and tuple(s) not in old:
                    seen += 1
                    for x, y in (s[:2], s[2:]):
                        # Chebyshev distance: out of the keep-out square (seated people's shins reach 0.17 m past their chair)
                        assert max(abs(x - ax), abs(y - ay)) >= k - 0.2
    assert seen > 50


def test_session_change_checks_its_settings():
    assert OFFICE_DAY == SessionChange(**OFFICE_DAY.to_dict())
    for bad in ({"chair_moved": 1.5}, {"door_closed": -0.1}, {"chair_shift_m": -1.0}, {"window_emission": (2.0, 1.0)}):
        with pytest.raises(InvalidParameterError, match=next(iter(bad))):
            SessionChange(**bad)
    assert issubclass(InvalidParameterError, FingerlocError)


def test_describe_visit_says_what_changed():
    from fingerloc.sim.sessions import describe_visit

    pairs = make_office_sessions(3, similarity=0.8, random_state=7, world="paper", change=EVERYTHING, change_random_state=2)
    for tr, te in pairs:
        words = describe_visit(tr, te)
        assert "seated" in words or "standing" in words
        assert "closed" in words and "lamps off" in words
        assert describe_visit(tr, tr) == "nothing changed"
    same = make_office_sessions(2, similarity=0.8, random_state=5, world="paper", change=NOTHING)
    assert all(describe_visit(tr, te) == "nothing changed" for tr, te in same)
