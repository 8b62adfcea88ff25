"""The robot's perception errors (``fingerloc.sim.perception``): missed, moved and spurious features."""

import math
import re
from pathlib import Path

import numpy as np
import pytest

from fingerloc.angles import dist_as
from fingerloc.errors import InvalidParameterError
from fingerloc.observation import Observation
from fingerloc.sim import PAPER_ROBOT, PAPER_VISIT, PerceptionNoise, perceive

DOCS = Path(__file__).resolve().parents[1] / "docs" / "METHOD.md"


def _obs(n: int = 40) -> Observation:
    b = np.linspace(-math.pi, math.pi, n, endpoint=False) + 0.01
    return Observation(ve=b, cp=b[:10], cp_hue=np.linspace(5, 350, 10), ex=b, c=b, b=b[:20], label="p")


def test_no_errors_returns_the_observation_itself():
    o = _obs()
    assert perceive(o, PerceptionNoise(), np.random.default_rng(0)) is o
    assert PerceptionNoise().is_null and not PAPER_ROBOT.is_null


def test_detection_keeps_the_expected_share_and_spurious_adds_a_poisson_count():
    o = _obs()
    noise = PerceptionNoise(camera_detection=0.7, laser_detection=0.9, spurious={"ve": 2.0, "b": 0.5})
    rng = np.random.default_rng(1)
    got = [perceive(o, noise, rng) for _ in range(400)]
    ve = np.array([g.ve.size for g in got])
    c = np.array([g.c.size for g in got])
    b = np.array([g.b.size for g in got])
    # binomial means and Poisson means, 400 draws: 5 standard errors
    assert abs(ve.mean() - (0.7 * 40 + 2.0)) < 5 * math.sqrt(40 * 0.21 + 2.0) / 20
    assert abs(c.mean() - 0.9 * 40) < 5 * math.sqrt(40 * 0.09) / 20
    assert abs(b.mean() - (0.9 * 20 + 0.5)) < 5 * math.sqrt(20 * 0.09 + 0.5) / 20
    assert noise.expected_count("ve", 40) == pytest.approx(30.0) and noise.expected_count("ex", 10) == 9.0
    # a kept camera feature is one of the originals; the hues follow their patches
    kept = got[0]
    assert kept.cp.size == kept.cp_hue.size
    assert all(np.any(np.isclose(h, o.cp_hue)) for h in kept.cp_hue[: kept.cp.size]) or kept.cp.size == 0


def test_bearing_noise_has_its_standard_deviation_and_leaves_the_other_sensor():
    o = _obs(20)  # 18 deg apart: a 3 deg error leaves each feature nearest its original (half spacing = 3 sd)
    noise = PerceptionNoise(camera_bearing_deg=3.0)
    d = []
    for s in range(200):
        g = perceive(o, noise, np.random.default_rng(s))
        assert np.array_equal(g.c, o.c) and np.array_equal(g.b, o.b)
        d.append(np.degrees(np.min(np.abs(dist_as(o.ve[None, :], g.ve[:, None])), axis=1)))
    rms = float(np.sqrt(np.mean(np.concatenate(d) ** 2)))  # 4,000 errors: the sample sd within 5 %
    assert 2.85 < rms < 3.15


def test_two_settings_see_the_same_draws():
    o = _obs()
    a = perceive(o, PerceptionNoise(camera_detection=0.8), np.random.default_rng(5))
    b = perceive(o, PerceptionNoise(camera_detection=0.8, camera_bearing_deg=0.5), np.random.default_rng(5))
    assert a.ve.size == b.ve.size and np.max(np.abs(dist_as(a.ve, b.ve))) < math.radians(3)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"camera_detection": 1.5}, "camera_detection"),
        ({"laser_detection": -0.1}, "laser_detection"),
        ({"camera_bearing_deg": -1}, "camera_bearing_deg"),
        ({"spurious": {"zz": 1.0}}, "unknown feature type"),
        ({"spurious": {"ve": -1.0}}, "mean count"),
    ],
)
def test_settings_are_checked(kwargs, match):
    with pytest.raises(InvalidParameterError, match=match):
        PerceptionNoise(**kwargs)


def _documented() -> dict[str, float]:
    """The calibrated values of docs/METHOD.md's table (``| name | value | ...``) in the reproduction section."""
    text = DOCS.read_text(encoding="utf-8")
    section = text[text.index("### The simulated robot, calibrated") :]
    section = section[: section.index("\n#")] if "\n#" in section else section
    out = {}
    for m in re.finditer(r"^\| `([a-z_.]+)` \| ([0-9.]+)", section, flags=re.M):
        out[m.group(1)] = float(m.group(2))
    return out


def test_calibrated_values_are_those_documented():
    doc = _documented()
    ours = {
        "camera_detection": PAPER_ROBOT.camera_detection,
        "laser_detection": PAPER_ROBOT.laser_detection,
        "camera_bearing_deg": PAPER_ROBOT.camera_bearing_deg,
        "laser_bearing_deg": PAPER_ROBOT.laser_bearing_deg,
        **{f"spurious.{k}": v for k, v in PAPER_ROBOT.spurious.items()},
        "heading_offset_deg": PAPER_VISIT.heading_offset_deg,
    }
    assert set(doc) == set(ours)
    for k, v in ours.items():
        assert doc[k] == pytest.approx(v), k
