"""The appearance descriptor of a panorama and the appearance term ``A``."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.special import logsumexp

from fingerloc.errors import InvalidParameterError, NotFittedError
from fingerloc.features.vision import (
    APPEARANCE_VERSIONS,
    AppearanceParams,
    appearance_descriptor,
    observation_from_views,
)
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


def _other_scene() -> Panorama:
    return _pano(seed=3, wall_cols=(100, 200, 520, 650), patches=((20, 60, 300.0), (300, 360, 60.0), (560, 600, 180.0)))


def _l1(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.abs(a - b).sum())


def test_descriptor_blocks_and_size():
    """Per strip: squares of the colour / grey shares sum to 1 / strips, as do the gradient orientation and
    magnitude shares' (each number is sqrt(share / strips))."""
    p = AppearanceParams()
    d = appearance_descriptor(_pano())
    assert d.shape == (p.size,) == (222,)
    assert APPEARANCE_VERSIONS[p.size] == 2
    assert np.all(d >= 0)
    nc = p.hue_bins * len(p.sat_edges) + p.value_bins + 2
    per = d.reshape(p.strips, p.strip_size) ** 2
    assert np.allclose(per[:, :nc].sum(axis=1), 1.0 / p.strips)  # every pixel in one colour/grey/dark/blown bin
    assert np.allclose(per[:, nc : nc + p.orientation_bins].sum(axis=1), 1.0 / p.strips)
    assert np.allclose(per[:, nc + p.orientation_bins :].sum(axis=1), 1.0 / p.strips)


def test_descriptor_version_1_layout_still_available():
    """strips=1, no gradients, 12 harmonics: the 94 numbers of version 1 (the term tells the versions apart)."""
    p = AppearanceParams(strips=1, gradients=False, harmonics=12)
    assert p.size == 94 and APPEARANCE_VERSIONS[94] == 1
    assert appearance_descriptor(_pano(), strips=1, gradients=False, harmonics=12).shape == (94,)
    from fingerloc.terms.appearance import _DESCRIPTOR_VERSIONS

    assert _DESCRIPTOR_VERSIONS == APPEARANCE_VERSIONS


@settings(max_examples=15, deadline=None)
@given(shift=st.integers(min_value=1, max_value=719))
def test_descriptor_is_heading_free(shift):
    """Turning the robot rolls the panorama's columns; the descriptor stays (up to rounding)."""
    pano = _pano()
    rolled = Panorama(np.roll(pano.image, shift, axis=1))
    assert np.allclose(appearance_descriptor(rolled), appearance_descriptor(pano), atol=1e-9)


def test_descriptor_same_at_any_resolution():
    """A photo twice as large (each pixel a 2 x 2 block) gives the same descriptor: block means to ~720 columns."""
    pano = _pano()
    big = Panorama(np.repeat(np.repeat(pano.image, 2, axis=0), 2, axis=1))
    assert np.allclose(appearance_descriptor(big), appearance_descriptor(pano), atol=1e-6)


@pytest.mark.parametrize(
    "change",
    [
        lambda im: im * np.array([1.15, 1.0, 0.85], dtype=np.float32),  # a warm white balance
        lambda im: im * 0.7,  # a shorter exposure
        lambda im: im * 1.1,  # a longer one (the ceiling clips)
    ],
)
def test_colour_cast_and_exposure_barely_move_the_descriptor(change):
    """White balance and exposure normalisation: another cast or exposure of one scene moves the descriptor
    by less than a fifth of the distance to another room painted alike."""
    a = _pano()
    changed = Panorama(np.clip(change(a.image), 0.0, 1.0).astype(np.float32))
    da, dc, do = (appearance_descriptor(p) for p in (a, changed, _other_scene()))
    assert _l1(da, dc) < 0.2 * _l1(da, do)


def test_cool_cast_on_walls_at_the_grey_threshold_known_limit():
    """Known limit: this scene's beige walls sit on the grey / colour saturation edge (0.15); under a cool
    cast the grey-world balance picks other reference pixels and part of the walls changes bins. The
    scene stays nearer to itself than to another room, but not by a factor 5 (0.66 of the way). Repeating
    the balance until it settles cured this scene but lost on real photos (docs/RESULTS.md, the
    appearance term), so it is not done."""
    a = _pano()
    cool = Panorama(np.clip(a.image * np.array([0.88, 1.0, 1.12], dtype=np.float32), 0.0, 1.0))
    da, dc, do = (appearance_descriptor(p) for p in (a, cool, _other_scene()))
    assert _l1(da, dc) < 0.75 * _l1(da, do)


def test_different_scene_moves_the_descriptor():
    """Another room painted alike (other wall breaks and posters) is far; new noise on the same room is not."""
    a = _pano()
    again = _pano(seed=1)  # the same room, another noise draw
    da = appearance_descriptor(a)
    assert _l1(da, appearance_descriptor(again)) < 0.15 * _l1(da, appearance_descriptor(_other_scene()))


def test_strips_see_elevation():
    """Upside down, the same pixels: one strip without gradients cannot tell, the default strips can."""
    a = _pano()
    flipped = Panorama(np.ascontiguousarray(a.image[::-1]))
    kw = {"strips": 1, "gradients": False}
    assert np.allclose(appearance_descriptor(flipped, **kw), appearance_descriptor(a, **kw), atol=1e-12)
    assert _l1(appearance_descriptor(flipped), appearance_descriptor(a)) > 1.0


def test_descriptor_hue_goes_to_its_bin():
    """A uniform saturated red band fills the red, most saturated bin only, in every strip."""
    img = np.zeros((24, 64, 3), dtype=np.float32)
    img[..., 0] = 0.9
    img[..., 1] = 0.1
    img[..., 2] = 0.1
    p = AppearanceParams()
    d = appearance_descriptor(Panorama(img), white_balance=False).reshape(p.strips, p.strip_size)
    assert np.allclose(d[:, len(p.sat_edges) - 1], np.sqrt(1.0 / p.strips))  # hue bin 0, top saturation bin
    assert np.allclose(d[:, : p.hue_bins * len(p.sat_edges) + p.value_bins + 2].sum(axis=1), np.sqrt(1.0 / p.strips))


def test_gradient_orientation_oracle():
    """Vertical stripes (edges across the columns) put every gradient in orientation bin 0; horizontal
    stripes in the bin of 90 deg; a flat image has only the weakest magnitude bin."""
    p = AppearanceParams(strips=1)
    nc = p.hue_bins * len(p.sat_edges) + p.value_bins + 2
    cols = np.zeros((40, 64, 3), dtype=np.float32) + 0.3
    cols[:, ::8] = 0.8  # one bright column in 8: column gradients only
    rows = np.ascontiguousarray(np.transpose(cols, (1, 0, 2))[:, :40].repeat(2, axis=1)[:, :64])
    rows = np.zeros((40, 64, 3), dtype=np.float32) + 0.3
    rows[::8] = 0.8  # one bright row in 8: row gradients only (away from the band's border rows)
    for img, bin_ in ((cols, 0), (rows, p.orientation_bins // 2)):
        d = appearance_descriptor(Panorama(img), strips=1, white_balance=False) ** 2
        orient = d[nc : nc + p.orientation_bins]
        assert orient[bin_] == pytest.approx(1.0)
    flat = appearance_descriptor(Panorama(np.full((40, 64, 3), 0.5, dtype=np.float32)), strips=1) ** 2
    assert flat[nc + p.orientation_bins] == pytest.approx(1.0)  # magnitude below 0.005 everywhere
    assert np.allclose(flat[nc : nc + p.orientation_bins], 1.0 / p.orientation_bins)  # no gradient: uniform


def test_descriptor_bad_params():
    with pytest.raises(InvalidParameterError, match="sat_edges"):
        appearance_descriptor(_pano(), sat_edges=(0.5, 0.2))
    with pytest.raises(InvalidParameterError, match="hue_bins"):
        appearance_descriptor(_pano(), hue_bins=0)
    with pytest.raises(InvalidParameterError, match="strips"):
        appearance_descriptor(_pano(), strips=0)
    with pytest.raises(InvalidParameterError, match="harmonics"):
        appearance_descriptor(_pano(), harmonics=-1)
    with pytest.raises(InvalidParameterError, match="gradients"):
        appearance_descriptor(_pano(), gradients=1)
    with pytest.raises(InvalidParameterError, match="fewer than the 3 strips"):
        appearance_descriptor(Panorama(np.full((2, 64, 3), 0.5, dtype=np.float32)))
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


def test_old_database_new_query_names_the_descriptor_versions(tmp_path):
    """Places learned from version-1 descriptors (94 numbers), a query with version 2 (222): one clear
    error through a saved and loaded model, naming both versions; same-version queries still work."""
    from fingerloc.errors import FingerlocError
    from fingerloc.map.database import load_model, save_model
    from fingerloc.model import PlaceModel

    old = [_pano(seed=s) for s in (0, 1)] + [_other_scene()]
    v1 = {"strips": 1, "gradients": False, "harmonics": 12}
    train = [Observation(appearance=appearance_descriptor(p, **v1), label=lab) for p, lab in zip(old, "aab", strict=True)]
    model = PlaceModel(terms=("A",)).fit(train)
    save_model(model, tmp_path / "old.sqlite")
    loaded = load_model(tmp_path / "old.sqlite")
    assert loaded.predict([train[2]])[0] == "b"  # old features still work with the old database
    query = Observation(appearance=appearance_descriptor(_other_scene()))
    with pytest.raises(FingerlocError, match="descriptor versions 2 and 1") as err:
        loaded.predict([query])
    assert "\n" not in str(err.value)


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
