"""The report folder of ``fingerloc demo``: a Markdown page (and the same as HTML) with PNG figures.

:func:`robot_tables_markdown` renders the robot experiment's tables (beside the
paper's numbers) as Markdown; :func:`write_demo_report` draws the figures of one
simulated trial with :mod:`fingerloc.plot` and writes ``index.md`` and
``results.json`` into a folder, and ``index.html``, the same page for a browser.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..terms import MixtureTerm
from .robot import (
    PAPER_TABLE2,
    PAPER_TABLE3,
    PAPER_TABLE4,
    TABLE4_NAMES,
    RobotResult,
    TrialData,
    TrialEvaluation,
)

__all__ = [
    "FIGURES",
    "QUERY_FIGURE",
    "QueryExplanation",
    "confusion_matrix",
    "explain_query",
    "findings_markdown",
    "robot_tables_markdown",
    "term_scale_markdown",
    "write_demo_report",
]

#: The figure of the explained query (written when the trial has a test query).
QUERY_FIGURE = "query.png"

#: Figure files of the report, in page order, with their captions.
FIGURES: dict[str, str] = {
    "map.png": "The office of the example from above: walls, door frames, furniture, beacons (gold) and "
    "coloured posters; the eight training poses on the 40-70 cm circle (blue), the two test poses inside it "
    "(red) and, with `--random-heading`, the same two positions with a random heading (green).",
    "omni.png": "The raw omnidirectional image (equiangular mirror) at the first test pose: this donut, "
    "not the simulator's geometry, is what the vision extractor sees.",
    "panorama.png": "The donut unwarped into a panorama (columns = bearing) with the vertical edges (cyan) "
    "and colour patches (triangles, with their hue letter) the extractor found.",
    "scan.png": "The 360 deg laser scan (two 180 deg heads) at the same pose, in the robot frame, with the "
    "fitted lines, corners, extremities and beacons the extractor found.",
    "fingerprint.png": "The fingerprint of that measurement drawn around the robot: each letter at its bearing.",
    "mixture.png": "What the model learned of the place: the mixture of Gaussians (k = 5) fit by EM on the "
    "vertical-edge bearings of its eight training measurements.",
    "posterior.png": "The answer for the first test measurement: the posterior P(Loc | VE, Ex, Fp) over the ten offices.",
    "confusion.png": "All test measurements of the trial: true office against the program's answer (VE, Ex & Fp, k = 5).",
}


def _ci(mean: float, ci: tuple[float, float] | None, fmt: str, scale: float = 1.0) -> str:
    if ci is None:
        return f"{scale * mean:{fmt}}"
    return f"{scale * mean:{fmt}} [{scale * ci[0]:{fmt}}, {scale * ci[1]:{fmt}}]"


def robot_tables_markdown(res: RobotResult) -> str:
    """Tables II-IV and the random-heading row as Markdown, beside the paper's figures."""
    fci = res.feature_ci()
    cci = res.cell_ci()
    lines = []
    lines += [
        "### Table II: mean features per measurement",
        "",
        "| feature | ours | paper |",
        "|---|---:|---:|",
    ]
    for t, (m, _s) in res.feature_stats().items():
        paper = PAPER_TABLE2.get(t)
        lines.append(f"| {t} | {_ci(m, fci[t], '.1f')} | {'-' if paper is None else f'{paper:.1f}'} |")
    cells = res.cell_stats()
    lines += [
        "",
        "### Table III: string matching, right classification % / mean rank",
        "",
        "| method | ours % | ours mean rank | paper |",
        "|---|---:|---:|---:|",
    ]
    for key, label in (("minimum_energy", "minimum energy"), ("global_alignment", "global alignment")):
        a, _, r, _ = cells[("table3", key)]
        ca, cr = cci[("table3", key)]
        pa, pr = PAPER_TABLE3[key]
        lines.append(f"| {label} | {_ci(a, ca, '.1f', 100)} | {_ci(r, cr, '.2f')} | {100 * pa:.1f} / {pr:.2f} |")
    ks = list(res.protocol.ks)
    lines += [
        "",
        "### Table IV: Bayesian program, right classification % / mean rank (paper in brackets)",
        "",
        "| terms | " + " | ".join(f"k={k}" for k in ks) + " |",
        "|---|" + "---:|" * len(ks),
    ]
    for row in TABLE4_NAMES:
        if ("table4", row, str(ks[0])) not in cells:
            continue
        parts = []
        for k in ks:
            a, _, r, _ = cells[("table4", row, str(k))]
            ca, cr = cci[("table4", row, str(k))]
            p = PAPER_TABLE4.get(row, {}).get(k)
            ptxt = f" ({100 * p[0]:.1f} / {p[1]:.2f})" if p is not None else ""
            parts.append(f"{_ci(a, ca, '.1f', 100)} / {_ci(r, cr, '.2f')}{ptxt}")
        lines.append(f"| {TABLE4_NAMES[row]} | " + " | ".join(parts) + " |")
    if ("random_heading", "global_alignment") in cells:
        lines += [
            "",
            "### Random heading, cyclic matching (not in the paper)",
            "",
            "| method | right % | mean rank |",
            "|---|---:|---:|",
        ]
        a, _, r, _ = cells[("random_heading", "global_alignment")]
        ca, cr = cci[("random_heading", "global_alignment")]
        lines.append(f"| cyclic global alignment | {_ci(a, ca, '.1f', 100)} | {_ci(r, cr, '.2f')} |")
        for k in ks:
            a, _, r, _ = cells[("random_heading", "VE+Ex+Fp", str(k))]
            ca, cr = cci[("random_heading", "VE+Ex+Fp", str(k))]
            lines.append(
                f"| VE, Ex & fingerprint, k={k}, heading from cyclic alignment | "
                f"{_ci(a, ca, '.1f', 100)} | {_ci(r, cr, '.2f')} |"
            )
        err = res.heading_error_deg()
        if err is not None:
            lines += ["", f"Median heading error of the cyclic alignment (true place): {err:.1f} deg."]
    lines += ["", f"Brackets: {res.ci_method()}."]
    lines += ["", findings_markdown(res), term_scale_markdown(res)]
    return "\n".join(lines) + "\n"


def findings_markdown(res: RobotResult) -> str:
    """The paper's findings beside ours (:meth:`RobotResult.findings`) as a Markdown table."""
    n = len(res.trials)
    how = f"paired over {n} trials" if n > 1 else "paired over this trial's test queries"
    lines = [
        f"### The paper's findings (difference in right classification, points; 95 % interval {how})",
        "",
        "| finding | paper | ours | verdict |",
        "|---|---:|---:|---|",
    ]
    for f in res.findings():
        lines.append(f"| {f.claim} | {100 * f.paper:+.1f} | {_ci(f.ours, f.ci95, '+.1f', 100)} | {f.verdict} |")
    return "\n".join(lines) + "\n"


def term_scale_markdown(res: RobotResult) -> str:
    """How far each term moves the places, and the fitted weights (:meth:`RobotResult.term_stats`), as Markdown."""
    stats = res.term_stats()
    if not stats:
        return ""
    lines = [
        "### How far each term moves the places (nats), and the weights fit on the training views",
        "",
        "Median over the test queries of (largest - smallest log-likelihood over the places). The paper's "
        "P(Fp) = 1/(cost+1) spans little next to the mixtures: with weights of 1 the string barely counts.",
        "",
        "| k | VE | Ex | Fp, 1/(cost+1) | Fp, exp(-λ cost) | λ | fitted weights VE / Ex / Fp |",
        "|---|---:|---:|---:|---:|---:|---|",
    ]
    for k, st in stats.items():
        sp, w, lam = st["spread_nats"], st["fitted_weights"], st.get("fp_lambda")
        lines.append(
            f"| {k} | {sp['VE']:.1f} | {sp['Ex']:.1f} | {sp['Fp']:.2f} | {sp.get('Fp-exp', math.nan):.1f} | "
            + ("-" if lam is None else f"{lam:.2f}")
            + " | "
            + " / ".join(f"{w.get(t, math.nan):.2f}" for t in ("VE", "Ex", "Fp"))
            + " |"
        )
    return "\n".join(lines) + "\n"


@dataclass(frozen=True, slots=True)
class QueryExplanation:
    """Why the full program answered one test query as it did (what the demo report shows).

    Attributes
    ----------
    index : int
        Position of the query among the trial's test measurements.
    truth, answer : str
        The true place and the program's answer (the posterior's argmax).
    rival : str
        The place compared with the true one: the answer when it is wrong, else the runner-up.
    posterior : ndarray, shape (P,)
        The program's posterior over ``classes``.
    k : int
        Mixture components of the program explained.
    program : tuple of str
        Its terms: ``("VE", "Ex", "Fp")`` (the full program) or fewer.
    classes : list of str
    terms : dict
        Term (``"VE"``, ``"Ex"``, ``"Fp"``) -> (log-likelihood under ``truth``, under ``rival``), nats.
    fingerprint : str
        The query's fingerprint.
    nearest : dict
        ``"truth"`` / ``"rival"`` -> (the place's training fingerprint nearest the query by
        global alignment, its alignment cost).
    counts : dict
        Feature type -> (count in the query, mean count in the true place's training views).
    reason : str
        One paragraph: which terms pulled towards the answer, by how much, and what the query lacked.
    """

    index: int
    truth: str
    answer: str
    rival: str
    posterior: np.ndarray
    classes: list[str]
    terms: dict[str, tuple[float, float]]
    k: int
    program: tuple[str, ...]
    fingerprint: str
    nearest: dict[str, tuple[str, float]]
    counts: dict[str, tuple[int, float]]
    reason: str


#: Configurations searched, in order, for a wrongly answered query: (terms, largest k first).
_SEARCH: tuple[tuple[str, ...], ...] = (("VE", "Ex", "Fp"), ("VE", "Ex"), ("Ex",), ("VE",))


def _posterior(model: Any, test: list[Any], terms: tuple[str, ...]) -> np.ndarray:
    """Posterior of the program restricted to ``terms`` (weights 1), shape (n, P)."""
    from scipy.special import logsumexp

    ll = model.term_log_likelihoods(test)
    joint = np.asarray(sum(ll[t] for t in terms), dtype=np.float64)
    return np.asarray(np.exp(joint - logsumexp(joint, axis=1, keepdims=True)))


def explain_query(
    data: TrialData,
    ev: TrialEvaluation,
    index: int | None = None,
    *,
    k: int | None = None,
    terms: tuple[str, ...] | None = None,
) -> QueryExplanation | None:
    """Explain one test query of the Bayesian program.

    Parameters
    ----------
    data : TrialData
    ev : TrialEvaluation
        With ``ev.models`` (or ``ev.model``) set.
    index : int, optional
        The test query. Default: the first query the full program (VE, Ex, Fp) gets wrong
        with the largest k, else with the next smaller k, else the first one a program with
        fewer terms gets wrong (VE & Ex, then Ex, then VE; the explanation says which);
        when every configuration is right everywhere, the query the full program wins by
        the smallest margin.
    k, terms : optional
        Explain this configuration (mixture components, terms) instead of searching.

    Returns
    -------
    QueryExplanation or None
        None when the trial has no test query or no fitted model.
    """
    from ..align import alignment_costs
    from ..fingerprint import make_fingerprint

    test = data.observations("test")
    train = data.observations("train")
    models = dict(ev.models) if ev.models else ({ev.model.n_components: ev.model} if ev.model is not None else {})
    if not test or not models:
        return None
    ks = sorted(models, reverse=True)
    configs = [(kk, t) for t in _SEARCH for kk in ks] if (k is None and terms is None) else []
    if k is not None or terms is not None:
        configs = [(ks[0] if k is None else k, ("VE", "Ex", "Fp") if terms is None else tuple(terms))]
        if configs[0][0] not in models:
            raise ValueError(f"no model with k = {configs[0][0]} in this evaluation")
    chosen = None
    for kk, tt in configs:
        post = _posterior(models[kk], test, tt)
        wrong = np.flatnonzero(np.argmax(post, axis=1) != ev.truth)
        if index is not None or wrong.size or len(configs) == 1:
            chosen = (kk, tt, post, int(wrong[0]) if index is None and wrong.size else index)
            break
    if chosen is None:  # every configuration right: the full program's closest call
        kk, tt = ks[0], ("VE", "Ex", "Fp")
        post = _posterior(models[kk], test, tt)
        chosen = (kk, tt, post, None)
    k_used, terms_used, posterior, index = chosen
    answers = np.argmax(posterior, axis=1)
    if index is None:
        wrong = np.flatnonzero(answers != ev.truth)
        if wrong.size:
            index = int(wrong[0])
        else:
            rows = np.arange(len(test))
            other = posterior.copy()
            other[rows, ev.truth] = -np.inf
            index = int(np.argmin(posterior[rows, ev.truth] - other.max(axis=1)))
    q = test[index]
    t_col, a_col = int(ev.truth[index]), int(answers[index])
    if a_col == t_col:  # right: compare with the runner-up
        others = np.array(posterior[index], dtype=np.float64)
        others[t_col] = -np.inf
        r_col = int(np.argmax(others))
    else:
        r_col = a_col
    truth, answer, rival = ev.classes[t_col], ev.classes[a_col], ev.classes[r_col]
    ll = models[k_used].term_log_likelihoods([q])
    term_ll = {t: (float(v[0, t_col]), float(v[0, r_col])) for t, v in ll.items() if t in terms_used}
    fp = make_fingerprint(q)
    nearest: dict[str, tuple[str, float]] = {}
    for role, name in (("truth", truth), ("rival", rival)):
        own = [o for o in train if o.label == name]
        fps = [make_fingerprint(o) for o in own]
        costs = np.asarray(alignment_costs([fp], fps))[0]
        j = int(np.argmin(costs))
        nearest[role] = (fps[j].letters, float(costs[j]))
    own_truth = [o for o in train if o.label == truth]
    counts = {
        t: (int(q.bearings(t).size), float(np.mean([o.bearings(t).size for o in own_truth])))
        for t in ("VE", "Ex", "c", "B", "CP")
    }
    return QueryExplanation(
        index=index,
        truth=truth,
        answer=answer,
        rival=rival,
        posterior=np.asarray(posterior[index], dtype=np.float64),
        classes=list(ev.classes),
        terms=term_ll,
        k=int(k_used),
        program=tuple(terms_used),
        fingerprint=fp.letters,
        nearest=nearest,
        counts=counts,
        reason=_reason(truth, answer, rival, term_ll, nearest, counts) + _visit_note(data, truth),
    )


def _visit_note(data: TrialData, office: str) -> str:
    """What changed in ``office`` between the training and the test visit, as a sentence ("" if nothing)."""
    from ..sim.sessions import describe_visit

    turn = _visit_turn_deg(data, office)
    turned = f"the robot's heading {turn:+.0f} deg off the training visit's" if abs(turn) >= 1.0 else ""
    for before, after in zip(data.worlds, data.test_worlds or data.worlds, strict=True):
        if before.name == office and after is not before:
            what = describe_visit(before, after)
            what = turned if what == "nothing changed" and turned else ", ".join(v for v in (what, turned) if v)
            return f" Between the training and the test visit of {office}: {what}."
    return f" Between the training and the test visit of {office}: {turned}." if turned else ""


def _visit_turn_deg(data: TrialData, office: str) -> float:
    """Mean heading of the office's test measurements minus that of its training ones, degrees (0 if none)."""
    idx = next((i for i, w in enumerate(data.worlds) if w.name == office), None)
    heads = {r: [m.pose[2] for m in data.measurements if m.office == idx and m.role == r] for r in ("train", "test")}
    if not heads["train"] or not heads["test"]:
        return 0.0
    d = float(np.mean(heads["test"])) - float(np.mean(heads["train"]))
    return math.degrees(math.atan2(math.sin(d), math.cos(d)))


_PROGRAM_NAMES = {
    ("VE", "Ex", "Fp"): "VE, Ex & fingerprint",
    ("VE", "Ex"): "VE & Ex, no fingerprint",
    ("Ex",): "Ex only",
    ("VE",): "VE only",
}

_TERM_NAMES = {"VE": "the vertical-edge mixture", "Ex": "the extremity mixture", "Fp": "the fingerprint"}


def _reason(
    truth: str,
    answer: str,
    rival: str,
    terms: dict[str, tuple[float, float]],
    nearest: dict[str, tuple[str, float]],
    counts: dict[str, tuple[int, float]],
) -> str:
    if truth == answer:
        margin = sum(a - b for a, b in terms.values())
        return (
            f"The program answered this query right ({truth}), {margin:.1f} nats ahead of the runner-up {rival}; "
            f"nearest training fingerprints: cost {nearest['truth'][1]:.0f} ({truth}) against "
            f"{nearest['rival'][1]:.0f} ({rival})."
        )
    pull = {t: a - b for t, (b, a) in terms.items()}  # > 0: the term prefers the answer
    towards = [t for t, d in sorted(pull.items(), key=lambda kv: -kv[1]) if d > 0]
    against = [t for t, d in sorted(pull.items(), key=lambda kv: kv[1]) if d <= 0]
    parts = [f"The program answered {answer} instead of {truth}."]
    if towards:
        parts.append(
            "Pulling towards the wrong office: "
            + "; ".join(f"{_TERM_NAMES.get(t, t)} by {pull[t]:.1f} nats" for t in towards)
            + "."
        )
    if against:
        parts.append(
            "For the true office: "
            + "; ".join(f"{_TERM_NAMES.get(t, t)} by {-pull[t]:.1f} nats" for t in against)
            + f", not enough against a net {sum(pull.values()):.1f} nats for {answer}."
        )
    (_, c_t), (_, c_a) = nearest["truth"], nearest["rival"]
    parts.append(
        f"The query's fingerprint is {c_t:.0f} alignment cost from the nearest training fingerprint of {truth} "
        f"and {c_a:.0f} from that of {answer}."
    )
    if "Fp" not in terms and c_t < c_a:
        parts.append(
            "The fingerprint, which this program leaves out, points to the true office: the order of the "
            "features around the robot tells what their bearings alone do not."
        )
    missing = [
        f"{n} {t} (the true office's training views: {m:.1f} on average)"
        for t, (n, m) in counts.items()
        if m >= 1.0 and n <= 0.6 * m
    ]
    extra = [f"{n} {t} (training: {m:.1f})" for t, (n, m) in counts.items() if n >= 1.6 * max(m, 1.0)]
    if missing:
        parts.append("The query saw fewer features than its office usually shows: " + ", ".join(missing) + ".")
    if extra:
        parts.append("It saw more than usual: " + ", ".join(extra) + ".")
    if not missing and not extra:
        parts.append(
            "Its feature counts are ordinary for its office: the offices are alike (one corridor, the same "
            "furniture), and the bearings it saw fit the other office's mixtures about as well."
        )
    return " ".join(parts)


def confusion_matrix(ev: TrialEvaluation) -> np.ndarray:
    """Counts (true place, answer) of the full program's answers, shape (P, P)."""
    p = len(ev.classes)
    c = np.zeros((p, p), dtype=np.int64)
    if ev.posterior.size:
        for t, a in zip(ev.truth, np.argmax(ev.posterior, axis=1), strict=True):
            c[int(t), int(a)] += 1
    return c


def write_demo_report(
    out_dir: str | Path,
    data: TrialData,
    ev: TrialEvaluation,
    res: RobotResult,
    *,
    office: int = 0,
    timings: dict[str, float] | None = None,
) -> Path:
    """Draw the figures of one trial and write ``index.md`` and ``results.json`` into ``out_dir``.

    Parameters
    ----------
    out_dir : str or Path
        The report folder (created).
    data : TrialData
        The trial's measurements; those of ``office`` must keep their raw data.
    ev : TrialEvaluation
        Its evaluation (``ev.model`` set: the full program with the largest k).
    res : RobotResult
        The same evaluation as a one-trial result (for the tables and the JSON).
    office : int
        The office the figures show.
    timings : dict, optional
        Stage -> seconds, written on the page.

    Returns
    -------
    Path
        The page, ``out_dir / "index.md"``.
    """
    from .. import plot
    from ..features.laser import extract_laser_features
    from ..features.vision import extract_vision_features
    from ..fingerprint import make_fingerprint

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    world = data.worlds[office]
    mine = [m for m in data.measurements if m.office == office]
    by_role = {r: [m for m in mine if m.role == r] for r in ("train", "test", "test-random-heading")}
    shown = by_role["test"][0]
    if shown.scan is None or shown.panorama is None:
        raise ValueError("the shown office's measurements must keep their raw data (keep_raw)")
    plot.plot_office_map(
        world,
        out / "map.png",
        train_poses=[m.pose for m in by_role["train"]],
        test_poses=[m.pose for m in by_role["test"]],
        other_poses=[m.pose for m in by_role["test-random-heading"]],
    )
    if shown.omni is not None:
        plot.plot_image(shown.omni.image, out / "omni.png", title=f"{world.name}: raw omnidirectional image")
    vf = extract_vision_features(shown.panorama)
    plot.plot_panorama_features(shown.panorama, vf, out / "panorama.png", title=f"{world.name}: unwarped panorama")
    lf = extract_laser_features(shown.scan)
    plot.plot_scan_features(shown.scan, lf, out / "scan.png", title=f"{world.name}: laser scan, test pose 1")
    fp = make_fingerprint(shown.observation)
    plot.plot_fingerprint(fp, out / "fingerprint.png", title=f"{world.name}: fingerprint of test pose 1")
    model = ev.model
    place = model.places_[world.name]
    ve = model.terms_.get("VE")
    mixture = ve.mixtures_[model.column_of(world.name)] if isinstance(ve, MixtureTerm) else None
    if mixture is not None:
        w, mu, sg = mixture
        samples = np.concatenate([o.bearings("VE") for o in place.observations])
        plot.plot_mixture(
            w,
            mu,
            sg,
            out / "mixture.png",
            samples=samples,
            title=f"{world.name}: P(VE | Loc), k = {model.n_components}, from {len(place.observations)} training measurements",
        )
    test_idx = next(i for i, m in enumerate(m for m in data.measurements if m.role == "test") if m.office == office)
    plot.plot_posterior(ev.classes, ev.posterior[test_idx], out / "posterior.png", truth=world.name)
    plot.plot_confusion(confusion_matrix(ev), ev.classes, out / "confusion.png")

    why = explain_query(data, ev)
    if why is not None:
        verdict = "wrong" if why.truth != why.answer else "right, by the smallest margin"
        plot.plot_posterior(
            why.classes,
            why.posterior,
            out / QUERY_FIGURE,
            truth=why.truth,
            title=f"test query {why.index + 1} ({why.truth}), {_PROGRAM_NAMES.get(why.program, '')}, k = {why.k}: "
            f"answered {why.answer}, {verdict}",
        )
    js = res.to_json()
    if why is not None:
        js["explained_query"] = {
            "index": why.index,
            "k": why.k,
            "terms": list(why.program),
            "truth": why.truth,
            "answer": why.answer,
            "posterior": dict(zip(why.classes, (float(v) for v in why.posterior), strict=True)),
            "term_log_likelihood": {t: {"truth": a, "rival": b} for t, (a, b) in why.terms.items()},
            "fingerprint": why.fingerprint,
            "rival": why.rival,
            "nearest_training_fingerprint": {r: {"letters": f, "cost": c} for r, (f, c) in why.nearest.items()},
            "reason": why.reason,
        }
    (out / "results.json").write_text(json.dumps(js, indent=2) + "\n", encoding="utf-8")
    page = _page(data, ev, res, world.name, fp.letters, timings or {}, out, why)
    path = out / "index.md"
    path.write_text(page, encoding="utf-8")
    from ..reporting import write_markdown_page  # the same page as plain HTML, for a browser

    write_markdown_page(out / "index.html", page, title="fingerloc demo report")
    return path


def _page(
    data: TrialData,
    ev: TrialEvaluation,
    res: RobotResult,
    name: str,
    letters: str,
    timings: dict[str, float],
    out: Path,
    why: QueryExplanation | None = None,
) -> str:
    from .robot_findings import reference_story

    p = res.protocol
    perception = p.perception
    change = p.session_change
    turn_note = (
        f" (set by eye: at the later test visit it is off the training visit's by an angle per office, "
        f"{change.heading_offset_deg:g} deg standard deviation)"
        if change is not None and change.heading_offset_deg > 0
        else ""
    )
    n_meas = sum(1 for m in data.measurements if m.role in ("train", "test"))
    story = reference_story()
    top1 = float(np.mean(np.argmax(ev.posterior, axis=1) == ev.truth)) if ev.posterior.size else math.nan
    lines = [
        "# fingerloc demo report",
        "",
        "Topological global localization with fingerprints and Bayesian programming "
        "(Tapus, Heinzer, Siegwart, ICRA 2004), on the paper's robot experiment in simulation.",
        "",
        "## What was done",
        "",
        f"1. **Simulate**: {p.n_offices} offices that resemble each other; in each, {p.n_train} training "
        f"measurements on a circle of {100 * p.train_radius_m[0]:.0f}-{100 * p.train_radius_m[1]:.0f} cm radius "
        f"and {p.n_test} test measurements inside it, about the same heading{turn_note} ({n_meas} measurements). "
        "Each gives a raw "
        f"360 deg laser scan ({p.n_beams} beams, intensities) and a raw {p.omni_size[0]}x{p.omni_size[1]} "
        "omnidirectional image.",
        "2. **Extract**: laser corners, extremities and beacons from the scan; the donut unwarped to a panorama, "
        "then vertical edges and colour patches. No ground truth is used."
        + (
            " The robot's extractors then miss and invent a few features, as a real robot's do "
            f"(detection probability {perception.camera_detection:g} per feature)."
            if perception is not None
            else ""
        ),
        "3. **Learn**: per office, a mixture of Gaussians on the circle for each feature type (EM) and the "
        "training fingerprints.",
        f"4. **Localize**: the {p.n_offices * p.n_test} test measurements, by the Bayesian program "
        "P(Loc | VE, Ex, Fp) and by string matching alone.",
        "",
        f"Full program (VE, Ex & fingerprint, k = {max(p.ks)}): **{100 * top1:.0f}%** of the test measurements "
        "placed in the right office in this trial. `fingerloc reproduce robot` averages over many trials.",
        "",
        *(["## What reproduces, and what does not", "", *(f"    {line}" for line in story), ""] if story else []),
        "## Tables (one trial), beside the paper's robot",
        "",
        robot_tables_markdown(res),
        "## Figures",
        "",
    ]
    for fname, caption in FIGURES.items():
        if (out / fname).exists():
            title = fname.removesuffix(".png")
            lines += [f"### {title}", "", f"![{title}]({fname})", "", caption, ""]
    lines += [f"Fingerprint of the first test measurement of {name}: `{letters}`", ""]
    if why is not None:
        wrong = why.truth != why.answer
        lines += [
            "## One query the program gets wrong" if wrong else "## The closest call (no query was wrong)",
            "",
            (
                ""
                if why.program == ("VE", "Ex", "Fp")
                else "The full program (VE, Ex & fingerprint) answered every test query of this trial right at "
                "every k; here is one that a program with fewer terms gets wrong. "
            )
            + f"Test query {why.index + 1} of {len(ev.truth)}, taken in **{why.truth}**; the program "
            f"({_PROGRAM_NAMES.get(why.program, ' & '.join(why.program))}, k = {why.k}) answered **{why.answer}** "
            f"(posterior {why.posterior[why.classes.index(why.answer)]:.2f}"
            + (
                f" against {why.posterior[why.classes.index(why.truth)]:.2f} for {why.truth})."
                if wrong
                else f"; runner-up {why.rival} at {why.posterior[why.classes.index(why.rival)]:.2f})."
            ),
            "",
            f"![posterior of the query]({QUERY_FIGURE})",
            "",
            "| term | log-likelihood, " + why.truth + " (true) | log-likelihood, " + why.rival + " |",
            "|---|---:|---:|",
        ]
        lines += [f"| {t} | {a:.2f} | {b:.2f} |" for t, (a, b) in why.terms.items()]
        (f_t, c_t), (f_a, c_a) = why.nearest["truth"], why.nearest["rival"]
        lines += [
            "",
            "Fingerprints (the training ones are each place's nearest to the query by global alignment):",
            "",
            "| fingerprint | letters | alignment cost to the query |",
            "|---|---|---:|",
            f"| the query | `{why.fingerprint}` | - |",
            f"| {why.truth} (true place) | `{f_t}` | {c_t:.0f} |",
            f"| {why.rival} ({'the answer' if wrong else 'the runner-up'}) | `{f_a}` | {c_a:.0f} |",
            "",
            "Features in the query against the true office's training views (mean): "
            + ", ".join(f"{t} {n} ({m:.1f})" for t, (n, m) in why.counts.items())
            + ".",
            "",
            f"**Why it failed.** {why.reason}" if wrong else f"**Note.** {why.reason}",
            "",
        ]
    if timings:
        lines += ["## Timings", "", "| stage | seconds |", "|---|---:|"]
        lines += [f"| {k} | {v:.1f} |" for k, v in timings.items()]
        lines.append("")
    lines += [
        "Machine-readable figures: [results.json](results.json) (same layout as `fingerloc reproduce robot --json`).",
        "",
    ]
    return "\n".join(lines)
