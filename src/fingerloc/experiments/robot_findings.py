"""Which of the paper's findings the simulated robot experiment reproduces (see :mod:`fingerloc.experiments.robot`).

Each finding of the paper is a difference between two of its cells (right
classification, in [0, 1]): global alignment against minimum energy (Table
III), VE with the most against the fewest mixture components, VE & Ex against
the better single term, the full program against VE & Ex (Table IV, the
largest k). Ours is the same difference, paired: over trials (Student t on the
per-trial differences) with two trials or more, over the test queries (Student
t on the per-query differences of "right") with one. A finding **holds** when
the 95 % interval of our difference lies above 0, is **reversed** when it lies
below 0, and is **not shown** otherwise.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from .robot_eval import t_interval
from .robot_sim import PAPER_TABLE2, PAPER_TABLE3, PAPER_TABLE4

if TYPE_CHECKING:
    from .robot_result import RobotResult

__all__ = ["REFERENCE_RUN", "Finding", "paper_findings", "reference_story"]


@dataclass(frozen=True, slots=True)
class Finding:
    """One of the paper's findings, beside ours.

    Attributes
    ----------
    key : str
        Short name (``"ga_beats_me"``, ``"components_help_ve"``, ``"fusion_beats_single"``, ``"fp_helps"``).
    claim : str
        The finding in words.
    a, b : tuple of str
        The two cells compared (``a`` - ``b``), as paths of :meth:`RobotResult.cell_stats`.
    paper : float
        The paper's difference, right classification in [-1, 1].
    ours : float
        Our mean difference.
    ci95 : (float, float) or None
        Its 95 % interval (None when undefined).
    """

    key: str
    claim: str
    a: tuple[str, ...]
    b: tuple[str, ...]
    paper: float
    ours: float
    ci95: tuple[float, float] | None

    @property
    def verdict(self) -> str:
        """``"holds"``, ``"reversed"`` or ``"not shown"`` (the interval contains 0, or is undefined)."""
        if self.ci95 is None:
            return "not shown"
        lo, hi = self.ci95
        if lo > 0:
            return "holds"
        if hi < 0:
            return "reversed"
        return "not shown"

    def to_json(self) -> dict[str, Any]:
        """JSON record: key, claim, compared cells, paper, ours, ci95, verdict."""
        return {
            "key": self.key,
            "claim": self.claim,
            "a": "/".join(self.a),
            "b": "/".join(self.b),
            "paper": self.paper,
            "ours": self.ours,
            "ci95": None if self.ci95 is None else [float(self.ci95[0]), float(self.ci95[1])],
            "verdict": self.verdict,
        }


def _paper(key: tuple[str, ...]) -> float:
    if key[0] == "table3":
        return PAPER_TABLE3[key[1]][0]
    return PAPER_TABLE4[key[1]][int(key[2])][0]


def _difference(res: RobotResult, a: tuple[str, ...], b: tuple[str, ...]) -> tuple[float, tuple[float, float] | None]:
    """Mean of ``a - b`` (right classification) and its paired 95 % interval."""
    if len(res.trials) >= 2:
        d = np.array([tr.cells[a][0] - tr.cells[b][0] for tr in res.trials])
    else:
        tr = res.trials[0]
        d = (tr.ranks[a] == 1).astype(np.float64) - (tr.ranks[b] == 1).astype(np.float64)
    if d.size == 0:
        return 0.0, None
    ci = t_interval(d)
    if ci is not None:
        ci = (max(ci[0], -1.0), min(ci[1], 1.0))
    return float(d.mean()), ci


def paper_findings(res: RobotResult) -> list[Finding]:
    """The paper's findings that our tables can test, with our paired differences (module docstring).

    Needs the Table III cells and the Table IV rows VE, Ex, VE+Ex and VE+Ex+Fp; the
    Table IV findings use the smallest and the largest k of the protocol that the paper
    has (3 and 5 by default) and are left out when the protocol has none of them.
    """
    out: list[Finding] = []

    def add(key: str, claim: str, a: tuple[str, ...], b: tuple[str, ...], paper: float | None = None) -> None:
        if a not in res.trials[0].cells or b not in res.trials[0].cells:
            return
        ours, ci = _difference(res, a, b)
        out.append(Finding(key, claim, a, b, _paper(a) - _paper(b) if paper is None else paper, ours, ci))

    add(
        "ga_beats_me",
        "global alignment beats minimum energy (string matching alone, Table III)",
        ("table3", "global_alignment"),
        ("table3", "minimum_energy"),
    )
    ks = [k for k in res.protocol.ks if k in PAPER_TABLE4["VE"]]
    if not ks:
        return out
    lo, hi = str(min(ks)), str(max(ks))
    if lo != hi:
        add(
            "components_help_ve",
            f"more mixture components help VE (k = {hi} against k = {lo})",
            ("table4", "VE", hi),
            ("table4", "VE", lo),
        )
    means = res.cell_stats()
    single = max(("VE", "Ex"), key=lambda t: means[("table4", t, hi)][0] if ("table4", t, hi) in means else -1.0)
    add(
        "fusion_beats_single",
        f"VE & Ex beat the better single term ({single}, k = {hi})",
        ("table4", "VE+Ex", hi),
        ("table4", single, hi),
        # the paper's own better single term
        paper=_paper(("table4", "VE+Ex", hi)) - max(_paper(("table4", t, hi)) for t in ("VE", "Ex")),
    )
    add(
        "fp_helps",
        f"the full program (VE, Ex & fingerprint) beats VE & Ex (k = {hi})",
        ("table4", "VE+Ex+Fp", hi),
        ("table4", "VE+Ex", hi),
    )
    return out


#: The reference run of the ``paper`` world: ``fingerloc reproduce robot --trials 20 --seed 0`` (its
#: JSON's means and 95 % intervals, right classification in [0, 1]; docs/METHOD.md §5 gives the
#: tables). What :func:`reference_story` tells; a run of that command prints the same figures.
REFERENCE_RUN: dict[str, Any] = {
    "command": "fingerloc reproduce robot --trials 20 --seed 0",
    "world": "paper",
    # path -> (mean, 95 % interval low, high)
    "cells": {
        "table3/minimum_energy": (0.6275, 0.562, 0.693),
        "table3/global_alignment": (0.895, 0.8564, 0.9336),
        "table4/VE+Ex/5": (0.365, 0.3129, 0.4171),
        "table4/VE+Ex+Fp/5": (0.3925, 0.3409, 0.4441),
        "table4/VE+Ex+Fp-fit/5": (0.9075, 0.8709, 0.9441),
        "table4/VE+Ex+Fp-exp/5": (0.655, 0.5702, 0.7398),
    },
    # finding key -> (our mean difference, 95 % interval low, high)
    "findings": {
        "ga_beats_me": (0.2675, 0.2043, 0.3307),
        "components_help_ve": (-0.0425, -0.0856, 0.0006),
        "fusion_beats_single": (0.0475, 0.0023, 0.0927),
        "fp_helps": (0.027499999999999997, 0.0114, 0.0436),
    },
    # k = 5: how far the paper's fingerprint term and the VE mixture move the places (nats)
    "fp_nats": 0.66,
    "ve_nats": 114.0,
    # Table II: mean features per measurement
    "table2": {"VE": 5.67, "Ex": 6.18, "CP": 2.58, "B": 4.21},
    # the same 20 trials in world "paper-ideal" (perfect perception, the same heading at both
    # visits): right classification, means
    "ideal": {
        "world": "paper-ideal",
        "table3/minimum_energy": 0.9825,
        "table3/global_alignment": 0.98,
        "table4/VE+Ex/5": 0.6675,
    },
}


def reference_story(reference: dict[str, Any] | None = None) -> list[str]:
    """What the reproduction shows over many trials, in a few lines (the demo's first screen).

    Parameters
    ----------
    reference : dict, optional
        Figures as in :data:`REFERENCE_RUN` (the default).
    """
    ref = REFERENCE_RUN if reference is None else reference
    cells, found = ref["cells"], ref["findings"]
    if not cells:
        return []

    def pc(key: str) -> str:
        m, lo, hi = cells[key]
        return f"{100 * m:4.1f}% [{100 * lo:.1f}, {100 * hi:.1f}]"

    def fd(key: str) -> str:
        m, lo, hi = found[key]
        f = Finding(key, "", (), (), 0.0, m, (lo, hi))
        return f"{f.verdict} ({100 * m:+.1f} points [{100 * lo:+.1f}, {100 * hi:+.1f}]"

    p3, p4 = PAPER_TABLE3, PAPER_TABLE4
    k = max(int(c.rsplit("/", 1)[1]) for c in cells if c.startswith("table4/VE+Ex+Fp/"))
    full, ve_ex = f"table4/VE+Ex+Fp/{k}", f"table4/VE+Ex/{k}"
    diff3 = p3["global_alignment"][0] - p3["minimum_energy"][0]
    single = max(p4["VE"][5][0], p4["Ex"][5][0])
    lines = [f"What the reproduction shows over 20 trials ({ref['command']}, world {ref['world']}):"]
    if "table2" in ref:
        t2 = ref["table2"]
        lines.append(
            "  Table II, features per measurement: CALIBRATED  "
            + " ".join(f"{t} {t2[t]:.1f}" for t in PAPER_TABLE2)
            + " (paper "
            + " ".join(f"{PAPER_TABLE2[t]:.1f}" for t in PAPER_TABLE2)
            + ")"
        )
    lines += [
        "  Table III, string matching alone: CALIBRATED (the robot's perception errors and its heading",
        "  at the later visit were fit to it)",
        f"    minimum energy    {pc('table3/minimum_energy')}  paper {100 * p3['minimum_energy'][0]:.1f}%",
        f"    global alignment  {pc('table3/global_alignment')}  paper {100 * p3['global_alignment'][0]:.1f}%",
        f"    - global alignment beats minimum energy: {fd('ga_beats_me')}; paper {100 * diff3:+.1f})",
        "  Table IV, the Bayesian program: PREDICTED (nothing was fit to it)",
        f"    full program, k = {k}  {pc(full)}  paper {100 * p4['VE+Ex+Fp'][k][0]:.1f}%",
        f"    VE & Ex, k = {k}       {pc(ve_ex)}  paper {100 * p4['VE+Ex'][k][0]:.1f}%",
        f"    - more mixture components help VE: {fd('components_help_ve')}; paper "
        f"{100 * (p4['VE'][5][0] - p4['VE'][3][0]):+.1f})",
        f"    - VE & Ex beat the better single term: {fd('fusion_beats_single')}; paper "
        f"{100 * (p4['VE+Ex'][5][0] - single):+.1f})",
        f"    - the full program beats VE & Ex: {fd('fp_helps')}; paper "
        f"{100 * (p4['VE+Ex+Fp'][5][0] - p4['VE+Ex'][5][0]):+.1f})",
        "  Why the mixtures fall short: their bearings are absolute, and the heading offset that makes",
        "  minimum energy fail moves them too.",
    ]
    ideal = ref.get("ideal")
    if ideal and f"table4/VE+Ex/{k}" in ideal:
        string = min(ideal["table3/minimum_energy"], ideal["table3/global_alignment"])
        lines += [
            f"  With the heading kept (world {ideal['world']}) VE & Ex are at {100 * ideal[f'table4/VE+Ex/{k}']:.1f}% "
            f"(paper {100 * p4['VE+Ex'][k][0]:.1f}%), but string",
            f"  matching is right {100 * string:.0f}% of the time: with our matchers no one world gives both tables.",
        ]
    lines += [
        "  Why the string adds little: the paper's P(Fp) = 1/(cost+1) moves the places by "
        f"{ref['fp_nats']:.2f} nats,",
        f"  the VE mixture by {ref['ve_nats']:.0f}. On the mixtures' scale the string counts: "
        f"P(Fp) ~ exp(-lambda cost)",
        f"  {pc(f'table4/VE+Ex+Fp-exp/{k}')}, term weights fit {pc(f'table4/VE+Ex+Fp-fit/{k}')}",
    ]
    return lines
