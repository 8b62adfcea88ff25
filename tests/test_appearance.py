"""The appearance descriptor of a panorama and the appearance term ``A``."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.special import logsumexp

from fingerloc.errors import InvalidParameterError, NotFittedError
from fingerloc.features.vision import AppearanceParams, appearance_descriptor, observation_from_views
from fingerloc.observation import Observation
from fingerloc.sensors import Panorama
from fingerloc.terms.appearance import AppearanceTerm, fit_lambda
from fingerloc.terms.base import Term

from .features_world import paint_panorama

# ---------------------------------------------------------------------------
# descriptor


def _pano(seed: int = 0, **kw: object) -> Panorama:
    img, *_ = paint_panorama(seed=seed, **kw)
    return Panorama(img.astype(np.float32))


def test_descriptor_blocks_sum_to_one_and_size():
    p = AppearanceParams()
    d = appearance_descriptor(_pano())
    nh = p.hue_bins * len(p.sat_edges)
    assert d.shape == (p.size,)
    assert np.all(d >= 0)
    assert d[: nh + p.value_bins + 2].sum() == pytest.approx(1.0)  # every pixel in one colour/grey bin
    assert d[nh + p.value_bins + 2 :].sum() == pytest.approx(1.0)  # layout spectrum


@settings(max_examples=15, deadline=None)
@given(shift=st.integers(min_value=1, max_value=719))
def test_descriptor_is_heading_free(shift):
    """Turning the robot rolls the panorama's columns; the descriptor stays (up to rounding)."""
    pano = _pano()
    rolled = Panorama(np.roll(pano.image, shift, axis=1))
    assert np.allclose(appearance_descriptor(rolled), appearance_descriptor(pano), atol=1e-9)


def test_descriptor_tells_scenes_apart_despite_exposure():
    """A darker exposure of one scene stays nearer to it than another scene does."""
    a = _pano()
    darker = Panorama((a.image * 0.75).astype(np.float32))
    other = _pano(
        seed=3, wall_cols=(100, 200, 520, 650), patches=((20, 60, 300.0), (300, 360, 60.0), (560, 600, 180.0))
    )
    da, dd, do = (appearance_descriptor(p) for p in (a, darker, other))
    assert np.abs(da - dd).sum() < 0.5 * np.abs(da - do).sum()


def test_descriptor_hue_goes_to_its_bin():
    """A uniform saturated red band fills the red, most saturated bin only."""
    img = np.zeros((20, 64, 3), dtype=np.float32)
    img[..., 0] = 0.9
    img[..., 1] = 0.1
    img[..., 2] = 0.1
    d = appearance_descriptor(Panorama(img), white_balance=False)
    p = AppearanceParams()
    assert d[len(p.sat_edges) - 1] == pytest.approx(1.0)  # hue bin 0, top saturation bin


def test_descriptor_bad_params():
    with pytest.raises(InvalidParameterError, match="sat_edges"):
        appearance_descriptor(_pano(), sat_edges=(0.5, 0.2))
    with pytest.raises(InvalidParameterError, match="hue_bins"):
        appearance_descriptor(_pano(), hue_bins=0)
    with pytest.raises(InvalidParameterError, match="unknown appearance parameter 'bins'"):
        appearance_descriptor(_pano(), bins=3)


def test_observation_from_views_adds_descriptor_and_source():
    pano = _pano()
    obs = observation_from_views(panorama=pano, appearance=True, source="office/1.jpg")
    assert obs.source == "office/1.jpg"
    assert np.array_equal(obs.appearance, appearance_descriptor(pano))
    assert observation_from_views(panorama=pano).appearance is None


# ---------------------------------------------------------------------------
# the term


def _groups(rng: np.random.Generator, n_places: int = 4, per: int = 3, dim: int = 6, spread: float = 0.05):
    centres = rng.random((n_places, dim))
    groups = [
        [Observation(appearance=np.abs(c + spread * rng.standard_normal(dim)), label=str(j)) for _ in range(per)]
        for j, c in enumerate(centres)
    ]
    return groups, centres


def test_term_contract():
    t = AppearanceTerm()
    assert isinstance(t, Term) and t.name == "A" and t.heading_free


def test_log_likelihood_matches_brute_force_nearest_view():
    rng = np.random.default_rng(1)
    groups, centres = _groups(rng)
    term = AppearanceTerm().fit(groups)
    queries = [Observation(appearance=np.abs(c + 0.05 * rng.standard_normal(c.size))) for c in centres]
    ll = term.log_likelihood(queries)
    assert ll.shape == (len(queries), len(groups))
    for i, q in enumerate(queries):
        for j, g in enumerate(groups):
            d = min(float(np.abs(q.appearance - o.appearance).sum()) for o in g)
            assert ll[i, j] == pytest.approx(-term.lambda_ * d)
    assert np.array_equal(np.argmax(ll, axis=1), np.arange(len(groups)))


def test_hellinger_metric():
    rng = np.random.default_rng(2)
    groups, _ = _groups(rng)
    term = AppearanceTerm(metric="hellinger").fit(groups)
    q = groups[1][0]
    d = term.distances([q])
    expected = min(math.sqrt(((np.sqrt(q.appearance) - np.sqrt(o.appearance)) ** 2).sum()) for o in groups[2])
    assert d[0, 2] == pytest.approx(expected)
    assert d[0, 1] == 0.0  # the query is one of the place's views


def test_lambda_is_the_leave_one_out_optimum():
    """``lambda_`` maximises the mean leave-one-out log-probability of the right place (grid oracle)."""
    rng = np.random.default_rng(3)
    groups, _ = _groups(rng, spread=0.3)
    term = AppearanceTerm().fit(groups)
    views = [(o.appearance, j) for j, g in enumerate(groups) for o in g]
    c = np.full((len(views), len(groups)), np.inf)
    for i, (a, _) in enumerate(views):
        for k, (b, j) in enumerate(views):
            if k != i:
                c[i, j] = min(c[i, j], float(np.abs(a - b).sum()))
    truth = np.array([j for _, j in views])

    def objective(lam: float) -> float:
        ll = -lam * c
        return float((ll[np.arange(truth.size), truth] - logsumexp(ll, axis=1)).mean())

    grid = np.exp(np.linspace(math.log(1e-3), math.log(1e4), 4000))
    best = grid[int(np.argmax([objective(x) for x in grid]))]
    assert objective(term.lambda_) >= objective(best) - 1e-6
    assert term.lambda_ == pytest.approx(best, rel=0.02)
    # unknown cost: median distance to the nearest other place
    wrong = c.copy()
    wrong[np.arange(truth.size), truth] = np.inf
    assert term.unknown_cost_ == pytest.approx(float(np.median(wrong.min(axis=1))))


def test_fit_lambda_sharp_only_when_the_term_never_errs():
    """Perfectly separated places make the term sharp; one error keeps it moderate."""
    truth = np.array([0, 1, 0, 1])
    clean = np.array([[0.1, 1.0], [1.0, 0.1], [0.1, 1.0], [1.0, 0.1]])
    sharp = fit_lambda(clean, truth, bounds=(1e-3, 1e4))
    one_error = clean.copy()
    one_error[3] = [0.1, 1.0]  # the last view is nearer the wrong place
    lam = fit_lambda(one_error, truth, bounds=(1e-3, 1e4))
    assert 0.1 < lam < 10 and sharp > 10 * lam


def test_observations_without_descriptor_score_zero_and_unknown():
    rng = np.random.default_rng(4)
    groups, _ = _groups(rng)
    groups[3] = [Observation(label="3")]  # a place without descriptors
    term = AppearanceTerm().fit(groups)
    q = [Observation(), groups[0][0]]
    ll = term.log_likelihood(q)
    assert np.array_equal(ll[0], np.zeros(4))
    assert ll[1, 3] == pytest.approx(ll[1, :3].min())  # no descriptor: the row's worst distance
    unk = term.unknown_log_likelihood(q)
    assert unk.shape == (2,)
    assert unk[0] == 0.0 and unk[1] == pytest.approx(-term.lambda_ * term.unknown_cost_)


def test_state_round_trip():
    rng = np.random.default_rng(5)
    groups, _ = _groups(rng)
    term = AppearanceTerm(metric="hellinger").fit(groups)
    state = term.to_state()
    back = AppearanceTerm.from_state(state, groups)
    q = [o for g in groups for o in g]
    assert back.metric == "hellinger"
    assert np.array_equal(back.log_likelihood(q), term.log_likelihood(q))
    assert np.array_equal(back.unknown_log_likelihood(q), term.unknown_log_likelihood(q))


def test_update_keeps_calibration_and_adds_places():
    rng = np.random.default_rng(6)
    groups, _ = _groups(rng)
    term = AppearanceTerm().fit(groups[:3])
    lam = term.lambda_
    term.update(groups, [3])
    assert term.lambda_ == lam
    assert term.log_likelihood([groups[3][0]]).shape == (1, 4)
    assert int(np.argmax(term.log_likelihood([groups[3][0]]))) == 3


def test_term_errors():
    with pytest.raises(InvalidParameterError, match="metric must be one of"):
        AppearanceTerm(metric="cosine").fit([[Observation(appearance=[1.0])]])
    with pytest.raises(NotFittedError):
        AppearanceTerm().log_likelihood([Observation()])
    with pytest.raises(InvalidParameterError, match="same length"):
        AppearanceTerm().fit([[Observation(appearance=[1.0, 2.0])], [Observation(appearance=[1.0])]])
    term = AppearanceTerm().fit([[Observation(appearance=[1.0, 2.0])], [Observation(appearance=[2.0, 1.0])]])
    with pytest.raises(InvalidParameterError, match="length 3"):
        term.log_likelihood([Observation(appearance=[1.0, 2.0, 3.0])])
    with pytest.raises(InvalidParameterError, match="malformed"):
        AppearanceTerm().set_state({"metric": "l1"}, [])


# ---------------------------------------------------------------------------
# the observation fields and their JSON Lines form


def test_observation_appearance_and_source_fields():
    o = Observation(appearance=[0.5, 0.25, 0.25], source="a/b.jpg")
    assert o.appearance.dtype == np.float64 and not o.appearance.flags.writeable
    assert o == Observation(appearance=[0.5, 0.25, 0.25], source="a/b.jpg")
    assert o != Observation(appearance=[0.5, 0.25, 0.2], source="a/b.jpg")
    assert o != Observation(appearance=[0.5, 0.25, 0.25], source="a/c.jpg")
    assert o != Observation(source="a/b.jpg")
    r = o.rotated(1.0)
    assert np.array_equal(r.appearance, o.appearance) and r.source == "a/b.jpg"
    assert np.array_equal(o.with_label("x").appearance, o.appearance)


@pytest.mark.parametrize(
    ("value", "message"),
    [
        ([0.5, -0.1], "appearance: values must be finite and >= 0, got -0.1"),
        ([0.5, float("nan")], "appearance: values must be finite and >= 0"),
        ([[0.5, 0.5]], "appearance: must be a non-empty 1-D array"),
        ([], "appearance: must be a non-empty 1-D array"),
        (["a"], "appearance: must be a 1-D array of numbers"),
    ],
)
def test_observation_appearance_validated(value, message):
    with pytest.raises(InvalidParameterError, match=message.replace("(", r"\(").replace("[", r"\[")):
        Observation(appearance=value)


def test_observation_source_must_be_text():
    with pytest.raises(InvalidParameterError, match="source: must be a string"):
        Observation(source=3)  # type: ignore[arg-type]


def test_jsonl_round_trip_of_appearance_and_source(tmp_path):
    from fingerloc.io.jsonl import read_observations, write_observations

    obs = [
        Observation.from_degrees({"VE": [10.0]}, appearance=[0.125, 0.875], source="x/1.webp", label="p"),
        Observation.from_degrees({"VE": [20.0]}),
    ]
    path = tmp_path / "o.jsonl"
    write_observations(path, obs)
    text = path.read_text()
    assert '"appearance": [0.125, 0.875]' in text and '"source": "x/1.webp"' in text
    assert read_observations(path) == obs


@pytest.mark.parametrize(
    ("record", "message"),
    [
        ('{"features": {}, "appearance": [0.1, -2]}', r'"appearance" values must be >= 0, got -2'),
        ('{"features": {}, "appearance": "abc"}', r'"appearance" must be a non-empty list of numbers'),
        ('{"features": {}, "appearance": [true]}', r'"appearance" value must be a number'),
        ('{"features": {}, "source": 5}', r'"source" must be a string or null, got 5'),
    ],
)
def test_jsonl_bad_appearance_or_source(tmp_path, record, message):
    from fingerloc.errors import DataFormatError
    from fingerloc.io.jsonl import read_observations

    path = tmp_path / "bad.jsonl"
    path.write_text(record + "\n")
    with pytest.raises(DataFormatError, match=message) as err:
        read_observations(path)
    assert "bad.jsonl:1:" in str(err.value)
