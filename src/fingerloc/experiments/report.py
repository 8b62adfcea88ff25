"""The report folder of ``fingerloc demo``: a Markdown page with PNG figures.

:func:`robot_tables_markdown` renders the robot experiment's tables (beside the
paper's numbers) as Markdown; :func:`write_demo_report` draws the figures of one
simulated trial with :mod:`fingerloc.plot` and writes ``index.md`` and
``results.json`` into a folder.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from .robot import (
    PAPER_TABLE2,
    PAPER_TABLE3,
    PAPER_TABLE4,
    TABLE4_NAMES,
    RobotResult,
    TrialData,
    TrialEvaluation,
)

__all__ = ["FIGURES", "confusion_matrix", "robot_tables_markdown", "write_demo_report"]

#: Figure files of the report, in page order, with their captions.
FIGURES: dict[str, str] = {
    "map.png": "The office of the example from above: walls, door frames, furniture, beacons (gold) and "
    "coloured posters; the eight training poses on the 40-70 cm circle (blue), the two test poses inside it "
    "(red) and the same two positions with a random heading (green).",
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
    return "\n".join(lines) + "\n"


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
    if "VE" in place.mixtures:
        w, mu, sg = place.mixtures["VE"]
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

    js = res.to_json()
    (out / "results.json").write_text(json.dumps(js, indent=2) + "\n", encoding="utf-8")
    page = _page(data, ev, res, world.name, fp.letters, timings or {}, out)
    path = out / "index.md"
    path.write_text(page, encoding="utf-8")
    return path


def _page(
    data: TrialData,
    ev: TrialEvaluation,
    res: RobotResult,
    name: str,
    letters: str,
    timings: dict[str, float],
    out: Path,
) -> str:
    p = res.protocol
    n_meas = sum(1 for m in data.measurements if m.role in ("train", "test"))
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
        f"and {p.n_test} test measurements inside it, same heading ({n_meas} measurements). Each gives a raw "
        f"360 deg laser scan ({p.n_beams} beams, intensities) and a raw {p.omni_size[0]}x{p.omni_size[1]} "
        "omnidirectional image.",
        "2. **Extract**: laser corners, extremities and beacons from the scan; the donut unwarped to a panorama, "
        "then vertical edges and colour patches. No ground truth is used.",
        "3. **Learn**: per office, a mixture of Gaussians on the circle for each feature type (EM) and the "
        "training fingerprints.",
        f"4. **Localize**: the {p.n_offices * p.n_test} test measurements, by the Bayesian program "
        "P(Loc | VE, Ex, Fp) and by string matching alone.",
        "",
        f"Full program (VE, Ex & fingerprint, k = {max(p.ks)}): **{100 * top1:.0f}%** of the test measurements "
        "placed in the right office in this trial. `fingerloc reproduce robot` averages over many trials.",
        "",
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
    if timings:
        lines += ["## Timings", "", "| stage | seconds |", "|---|---:|"]
        lines += [f"| {k} | {v:.1f} |" for k, v in timings.items()]
        lines.append("")
    lines += [
        "Machine-readable figures: [results.json](results.json) (same layout as `fingerloc reproduce robot --json`).",
        "",
    ]
    return "\n".join(lines)
