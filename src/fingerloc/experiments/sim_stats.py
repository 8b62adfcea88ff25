"""Figures about the simulator for docs/RESULTS.md (``python -m fingerloc.experiments.sim_stats``).

1. Ground-truth features per measurement (the paper's protocol poses in ten
   offices), beside the paper's Table II means.
2. How alike the offices are for several ``similarity`` values: the share of
   ground-truth bearings (VE, c, Ex) at one office's anchor that another office
   also has within 5 deg at its anchor (same heading), against the same share
   between two poses of one office.
3. Laser intensities: beams on beacons against all other beams.

``python -m fingerloc.experiments.sim_stats calibrate``: the features the
extractors find per measurement in each world of the robot experiment
(:data:`~fingerloc.experiments.robot.WORLD_PROFILES`), beside Table II; for a
world whose test measurements are taken at a later visit (``"paper"``), the
training and the test pose's counts apart too (``train_VE``, ``test_VE``, ...);
for a world with perception errors, the mean counts after them
(``perceived_VE``, ...).

``python -m fingerloc.experiments.sim_stats table3 [--trials N] [--seed S]
[--noise-seeds 0,1] [--table4 3,4,5] VARIANT ...``: :func:`table3_sweep`, the
calibration of the robot's perception errors and of the later visit's heading
on the paper's Table III (``--table4``: Table IV too, as a diagnostic); each
VARIANT is a JSON object (see :func:`table3_sweep`).
"""

from __future__ import annotations

import json
import math
import sys
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from ..angles import dist_as
from ..errors import InvalidParameterError
from ..sim import make_offices, protocol_poses, simulate_scan, true_features
from ..sim.laser import LASER_HEIGHT
from ..sim.world import cast_rays
from .robot import PAPER_TABLE2

__all__ = ["calibration_counts", "feature_counts", "intensity_stats", "main", "office_likeness", "table3_sweep"]

_TYPES = ("VE", "Ex", "c", "CP", "B")
_FIELD = {"VE": "ve", "Ex": "ex", "c": "c", "CP": "cp", "B": "b"}


def feature_counts(
    n_offices: int = 10, *, similarity: float = 0.5, seed: int = 0, world: str = "alike"
) -> dict[str, float]:
    """Mean number of ground-truth features per measurement over the protocol poses."""
    rng = np.random.default_rng(seed)
    counts: dict[str, list[int]] = {k: [] for k in _TYPES}
    for w in make_offices(n_offices, similarity=similarity, random_state=rng, world=world):
        train, test = protocol_poses(w, random_state=rng)
        for pose in np.vstack([train, test]):
            f = true_features(w, tuple(pose))
            for k in _TYPES:
                counts[k].append(int(f[k].size))
    return {k: float(np.mean(v)) for k, v in counts.items()}


def _match_share(a: dict[str, np.ndarray], b: dict[str, np.ndarray], tol: float) -> float:
    hit = tot = 0
    for k in ("VE", "c", "Ex"):
        if a[k].size == 0:
            continue
        tot += a[k].size
        if b[k].size:
            hit += int((np.abs(dist_as(a[k][:, None], b[k][None, :])).min(axis=1) <= tol).sum())
    return hit / max(tot, 1)


def office_likeness(similarity: float, *, n_offices: int = 10, seed: int = 0, tol_deg: float = 5.0) -> dict[str, float]:
    """Share of bearings matched across offices (anchors) and within an office (anchor vs a pose 0.55 m away)."""
    tol = np.deg2rad(tol_deg)
    worlds = make_offices(n_offices, similarity=similarity, random_state=seed)
    truths = [true_features(w, (*w.anchor, 0.0)) for w in worlds]
    across = [_match_share(truths[i], truths[j], tol) for i in range(n_offices) for j in range(n_offices) if i != j]
    within = []
    for w, t in zip(worlds, truths, strict=True):
        p = (w.anchor[0] + 0.55, w.anchor[1], 0.0)
        within.append(_match_share(t, true_features(w, p), tol))
    return {"across_offices": float(np.mean(across)), "within_office": float(np.mean(within))}


def intensity_stats(n_offices: int = 10, *, seed: int = 0) -> dict[str, float]:
    """Percentiles of the intensity of beacon beams and of all other beams (720-beam scans at the anchors)."""
    on, off = [], []
    for w in make_offices(n_offices, random_state=seed):
        pose = (*w.anchor, 0.0)
        scan = simulate_scan(w, pose, random_state=seed)
        _, seg, _ = cast_rays(w, pose[:2], scan.bearings + pose[2], z=LASER_HEIGHT)
        beacon = np.zeros(seg.size, dtype=bool)
        hit = (seg >= 0) & scan.valid
        mats = w.surface_material(seg[hit], LASER_HEIGHT)
        beacon[hit] = [w.materials[m].beacon for m in mats]
        assert scan.intensities is not None
        on.append(scan.intensities[beacon])
        off.append(scan.intensities[hit & ~beacon])
    a, b = np.concatenate(on), np.concatenate(off)
    return {
        "beacon_beams": int(a.size),
        "beacon_p5": float(np.percentile(a, 5)),
        "beacon_median": float(np.median(a)),
        "other_p50": float(np.percentile(b, 50)),
        "other_p95": float(np.percentile(b, 95)),
        "other_p99": float(np.percentile(b, 99)),
        "other_max": float(b.max()),
    }


def calibration_counts(
    *,
    world: str = "paper",
    similarity: float = 0.8,
    templates: int = 5,
    blur: float = 1.5,
    noise: float = 0.025,
    jpeg_quality: int = 75,
    edge_params: dict[str, float] | None = None,
    seed: int = 100,
    session: dict[str, Any] | None = None,
) -> dict[str, float]:
    """Features the extractors find per measurement, for calibrating a world to the paper's Table II.

    ``templates`` sets of ten offices (seeds ``seed``, ``seed + 1``, ...; each set shares one
    template, so several are needed to average over templates), two measurements per office
    (the first training pose and the first test pose of the protocol), the raw sensors (the
    robot experiment's 360 deg laser and 640x480 omnidirectional camera with the given
    ``blur`` (pixels), ``noise`` and JPEG quality), then the extractors: laser ``Ex``, ``B``,
    ``c`` with their defaults, colour patches with theirs, vertical edges with
    ``edge_params`` (fields of :class:`~fingerloc.features.vision.EdgeParams`). With
    ``session`` (:class:`~fingerloc.sim.sessions.SessionChange` fields), the test pose is
    measured at the later visit of the office (changes drawn with seed ``seed + 1000 + t``).

    Returns
    -------
    dict
        Feature type -> mean count per measurement; ``"truth_VE"`` etc.: the simulator's
        ground truth (:func:`~fingerloc.sim.true_features`) at the same poses; ``"train_VE"``,
        ``"test_VE"`` etc.: the extracted counts of the training and the test pose alone; ``"n"``.
    """
    from ..features.laser import extract_laser_features
    from ..features.vision import colour_patches, unwarp_omni, vertical_edges
    from ..sim import render_omni
    from ..sim.sessions import SessionChange, make_office_sessions
    from .robot import RobotProtocol, measurement_poses

    p = RobotProtocol(random_heading=False)
    got: dict[str, list[int]] = {k: [] for k in _TYPES}
    truth: dict[str, list[int]] = {k: [] for k in _TYPES}
    role: list[str] = []
    change = None if session is None else SessionChange(**session)
    for t in range(templates):
        rng = np.random.default_rng(seed + t)
        pairs = make_office_sessions(
            10, random_state=rng, world=world, similarity=similarity, change=change, change_random_state=seed + 1000 + t
        )
        for w0, w1 in pairs:
            train, test = measurement_poses(w0, p, rng)
            for w, pose, r in ((w0, train[0], "train"), (w1, test[0], "test")):
                role.append(r)
                scan = simulate_scan(w, pose, random_state=rng)
                im = render_omni(w, pose, jpeg_quality=jpeg_quality, blur=blur, noise=noise, random_state=rng)
                off = im.forward_angle if im.clockwise else -im.forward_angle
                pano = unwarp_omni(
                    im.image, im.center, im.radii[0], im.radii[1], bearing_offset=off, mirror=im.clockwise, width=720
                )
                lf = extract_laser_features(scan)
                got["Ex"].append(lf.extremities.size)
                got["B"].append(lf.beacons.size)
                got["c"].append(lf.corners.size)
                got["CP"].append(colour_patches(pano)[0].size)
                got["VE"].append(vertical_edges(pano, **(edge_params or {})).size)
                tf = true_features(w, pose)
                for k in _TYPES:
                    truth[k].append(int(tf[k].size))
    out = {k: float(np.mean(v)) for k, v in got.items()}
    out.update({f"truth_{k}": float(np.mean(v)) for k, v in truth.items()})
    roles = np.array(role)
    for r in ("train", "test"):
        out.update({f"{r}_{k}": float(np.mean(np.array(v)[roles == r])) for k, v in got.items()})
    out["n"] = float(len(got["VE"]))
    return out


def _variant_noise(v: Mapping[str, Any], counts: Mapping[str, float]) -> tuple[Any, float]:
    """A sweep variant -> (PerceptionNoise, heading offset in degrees); see :func:`table3_sweep`."""
    from ..sim.perception import PerceptionNoise

    known = {"detection", "camera_detection", "laser_detection", "camera_bearing_deg", "laser_bearing_deg"}
    bad = set(v) - known - {"spurious", "heading_offset_deg"}
    if bad:
        raise InvalidParameterError(f"table3 variant: unknown keys {sorted(bad)} (known: {sorted(known)}, spurious, "
                                    "heading_offset_deg)")  # fmt: skip
    p_cam = float(v.get("camera_detection", v.get("detection", 1.0)))
    p_las = float(v.get("laser_detection", v.get("detection", 1.0)))
    spur = v.get("spurious", "balanced")
    if spur == "balanced":  # as many false features as lost, on average: the mean counts stay
        spur = {k: (1.0 - (p_cam if k in ("ve", "cp") else p_las)) * counts[k] for k in ("ve", "cp", "c", "ex", "b")}
    noise = PerceptionNoise(
        camera_detection=p_cam,
        laser_detection=p_las,
        camera_bearing_deg=float(v.get("camera_bearing_deg", 0.0)),
        laser_bearing_deg=float(v.get("laser_bearing_deg", 0.0)),
        spurious=dict(spur),
    )
    return noise, float(v.get("heading_offset_deg", 0.0))


def table3_sweep(
    variants: Sequence[Mapping[str, Any]],
    *,
    trials: int = 20,
    seed: int = 0,
    noise_seeds: Sequence[int] = (0,),
    world: str = "paper-ideal",
    protocol: Any = None,
    table4_ks: Sequence[int] = (),
    workers: int | None = None,
    on_trial: Callable[[int], None] | None = None,
) -> list[dict[str, Any]]:
    """Table III under candidate perception errors and later-visit headings: how :data:`~fingerloc.sim.PAPER_ROBOT` and :data:`~fingerloc.sim.PAPER_VISIT` were chosen.

    The trials of ``world`` (default ``"paper-ideal"``: the ``"paper"`` offices and visits, perfect
    perception, the same heading at both visits) are simulated once (``reproduce robot``'s
    trials ``(seed, t)``); each variant then changes the extracted features as the robot
    experiment does (:func:`~fingerloc.sim.perceive` on every measurement, the test
    measurements of each office turned by one heading offset), and Table III is computed.
    The offset turns the features instead of the robot (the rendered robot is turned in
    ``reproduce robot``): the same up to the sensors' pixel and beam grids.

    Parameters
    ----------
    variants : sequence of mapping
        Keys: ``detection`` (both sensors), ``camera_detection``, ``laser_detection``
        (probabilities, default 1), ``camera_bearing_deg``, ``laser_bearing_deg`` (default 0),
        ``spurious`` (``"balanced"``, the default: as many false features of each type as are
        lost on average, from the trials' own mean counts; or a mapping type -> mean count),
        ``heading_offset_deg`` (standard deviation of the later visit's heading, one per office;
        default 0).
    trials, seed : int
        The simulated trials (``(seed, t)`` for ``t < trials``).
    noise_seeds : sequence of int
        Each variant is drawn with each of these seeds and the figures averaged (one seed's
        draws are the same for every variant: common random numbers).
    world : str
        The world simulated (:data:`~fingerloc.experiments.robot.WORLD_PROFILES`).
    protocol : RobotProtocol, optional
        Instead of the paper's protocol in ``world`` (smaller runs, tests); its own perception
        errors and heading changes come on top of the variants'.
    table4_ks : sequence of int
        Also Table IV's rows (VE, Ex, VE+Ex, VE+Ex+Fp, and the extra rows VE+Ex+Fp-fit and
        VE+Ex+Fp-exp) with these k, as ``reproduce robot`` computes them: a diagnostic of a
        world, never used to choose one (default: none).
    workers : int, optional
        Processes, one trial each (default: the usable cores, at most 4; 1: in this process).
        The figures do not depend on it.
    on_trial : callable(done), optional
        Called after each simulated trial.

    Returns
    -------
    list of dict
        Per variant: ``variant``, ``perception`` (the settings used), ``heading_offset_deg``,
        ``minimum_energy`` and ``global_alignment`` (``top1``, ``mean_rank``: means over trials
        and noise seeds; ``top1_per_seed``), ``counts`` (Table II after the errors), and with
        ``table4_ks`` the same for ``"table4/ROW/k"``.
    """
    from .robot import RobotProtocol, default_workers, simulation_pool

    if protocol is None:
        protocol = RobotProtocol(world=world, random_heading=False)
    n_workers = default_workers() if workers is None else max(1, int(workers))
    with simulation_pool(min(n_workers, trials)) as ex:
        mapper = map if ex is None else ex.map
        data = []
        for t, d in enumerate(mapper(_sweep_simulate, [(protocol, seed, t) for t in range(trials)])):
            data.append(d)
            if on_trial is not None:
                on_trial(t + 1)
        every = [o for d in data for role in ("train", "test") for o in d[role]]
        counts = {k: float(np.mean([getattr(o, k).size for o in every])) for k in ("ve", "cp", "c", "ex", "b")}
        resolved = [_variant_noise(v, counts) for v in variants]
        jobs = [(d, t, seed, resolved, tuple(noise_seeds), tuple(table4_ks)) for t, d in enumerate(data)]
        per_trial = list(mapper(_sweep_evaluate, jobs))
    out = []
    for i, v in enumerate(variants):
        noise, offset_deg = resolved[i]
        rec: dict[str, Any] = {"variant": dict(v), "perception": noise.to_dict(), "heading_offset_deg": offset_deg}
        figs = {name: [pt[i][0][name] for pt in per_trial] for name in per_trial[0][i][0]}  # name -> trial -> seed
        for name, f in figs.items():
            arr = np.array(f)  # (trials, seeds, 2)
            rec[name] = {
                "top1": float(arr[:, :, 0].mean()),
                "mean_rank": float(arr[:, :, 1].mean()),
                "top1_per_seed": [float(x) for x in arr[:, :, 0].mean(axis=0)],
            }
        rec["counts"] = {k: float(np.mean([c for pt in per_trial for c in pt[i][1][k]])) for k in per_trial[0][i][1]}
        out.append(rec)
    return out


def _sweep_simulate(args: tuple[Any, int, int]) -> dict[str, Any]:
    """One trial of :func:`table3_sweep`: its place names and its training and test observations."""
    from .robot import simulate_trial

    protocol, seed, t = args
    d = simulate_trial(protocol, (seed, t))
    return {"classes": [w.name for w in d.worlds], "train": d.observations("train"), "test": d.observations("test")}


def _sweep_evaluate(args: tuple[Any, ...]) -> list[tuple[dict[str, list[tuple[float, float]]], dict[str, list[int]]]]:
    """Every variant on one trial of :func:`table3_sweep`: per variant, (cell -> per noise seed (top1, mean
    rank), feature type -> counts per measurement)."""
    from ..align import alignment_costs, minimum_energy_costs
    from ..fingerprint import make_fingerprint
    from ..metrics import min_per_place, true_place_ranks
    from ..sim.perception import perceive
    from .robot import TABLE2_TYPES

    d, t, seed, resolved, noise_seeds, table4_ks = args
    classes = d["classes"]
    col = {c: j for j, c in enumerate(classes)}
    out = []
    for noise, offset_deg in resolved:
        figs: dict[str, list[tuple[float, float]]] = {"minimum_energy": [], "global_alignment": []}
        seen: dict[str, list[int]] = {k: [] for k in TABLE2_TYPES}
        for s in noise_seeds:
            off = math.radians(offset_deg) * np.random.default_rng([s, t, 2]).standard_normal(len(classes))
            obs: dict[str, list[Any]] = {"train": [], "test": []}
            for role, rid in (("train", 0), ("test", 1)):
                for i, o in enumerate(d[role]):
                    o = perceive(o, noise, np.random.default_rng([s, t, rid, i]))
                    obs[role].append(o.rotated(-off[col[str(o.label)]]) if rid else o)
            for o in obs["train"] + obs["test"]:
                for k in TABLE2_TYPES:
                    seen[k].append(o.bearings(k).size)
            owner = np.array([col[str(o.label)] for o in obs["train"]])
            truth = np.array([col[str(o.label)] for o in obs["test"]])
            tf = [make_fingerprint(o) for o in obs["train"]]
            qf = [make_fingerprint(o) for o in obs["test"]]
            for name, costs in (
                ("minimum_energy", minimum_energy_costs(qf, tf, workers=1)),
                ("global_alignment", alignment_costs(qf, tf, workers=1)),
            ):
                rk = true_place_ranks(-min_per_place(costs, owner, len(classes)), truth)
                figs[name].append((float(np.mean(rk == 1)), float(np.mean(rk))))
            for n_comp in table4_ks:
                for row, rk in _table4_ranks(obs["train"], obs["test"], truth, n_comp, seed * 1000 + t).items():
                    figs.setdefault(f"table4/{row}/{n_comp}", []).append((float(np.mean(rk == 1)), float(np.mean(rk))))
        out.append((figs, seen))
    return out


def _table4_ranks(train: list[Any], test: list[Any], truth: Any, k: int, random_state: int) -> dict[str, Any]:
    """Ranks of the true place for Table IV's rows (as :func:`~fingerloc.experiments.robot.evaluate_trial`)."""
    from ..metrics import true_place_ranks
    from ..model import PlaceModel
    from .robot import TABLE4_EXP, TABLE4_FITTED, TABLE4_TERMS

    model = PlaceModel(k, terms=("VE", "Ex", "Fp"), random_state=random_state).fit(train)
    ll = model.term_log_likelihoods(test)
    out = {row: true_place_ranks(sum(ll[t] for t in terms), truth) for row, terms in TABLE4_TERMS.items()}
    fitted = PlaceModel(k, terms=("VE", "Ex", "Fp"), weights="fit", random_state=random_state).fit(train)
    out[TABLE4_FITTED] = true_place_ranks(fitted.predict_log_proba(test), truth)
    fp = PlaceModel(k, terms=("Fp",), fp_likelihood="exp", random_state=random_state).fit(train)
    out[TABLE4_EXP] = true_place_ranks(ll["VE"] + ll["Ex"] + fp.term_log_likelihoods(test)["Fp"], truth)
    return out


def _table3_main(args: list[str]) -> list[dict[str, Any]]:
    trials, seed, seeds, variants, ks = 20, 0, [0], [], []
    it = iter(args)
    for a in it:
        if a == "--table4":
            ks = [int(x) for x in next(it).split(",")]
        elif a == "--trials":
            trials = int(next(it))
        elif a == "--seed":
            seed = int(next(it))
        elif a == "--noise-seeds":
            seeds = [int(x) for x in next(it).split(",")]
        else:
            variants.append(json.loads(a))
    res = table3_sweep(variants or [{}], trials=trials, seed=seed, noise_seeds=seeds, table4_ks=ks)
    for r in res:
        me, ga = r["minimum_energy"], r["global_alignment"]
        sys.stderr.write(
            f"{json.dumps(r['variant'])}: minimum energy {100 * me['top1']:.1f}% / {me['mean_rank']:.2f}, "
            f"global alignment {100 * ga['top1']:.1f}% / {ga['mean_rank']:.2f}\n"
        )
        for key in (k for k in r if k.startswith("table4/")):
            sys.stderr.write(f"    {key}: {100 * r[key]['top1']:.1f}% / {r[key]['mean_rank']:.2f}\n")
    json.dump(res, sys.stdout, indent=1)
    sys.stdout.write("\n")
    return res


def main(argv: list[str] | None = None) -> Any:
    """Print the figures as JSON; ``calibrate`` as the first argument: :func:`calibration_counts` of every world;
    ``table3``: :func:`table3_sweep` (module docstring)."""
    args = sys.argv[1:] if argv is None else argv
    if args[:1] == ["table3"]:
        return _table3_main(args[1:])
    if args[:1] == ["calibrate"]:
        from .robot import WORLD_PROFILES

        cal: dict[str, Any] = {}
        for world, prof in WORLD_PROFILES.items():
            cal[world] = calibration_counts(
                world=prof["offices"],
                session=prof["session"],
                similarity=prof["similarity"],
                blur=prof["blur"],
                noise=prof["noise"],
                jpeg_quality=prof["jpeg_quality"],
                edge_params=prof["extractor"],
            )
            if prof.get("perception"):
                from ..sim.perception import PerceptionNoise

                pn = PerceptionNoise(**prof["perception"])
                for t in ("VE", "Ex", "CP", "B", "c"):
                    cal[world][f"perceived_{t}"] = pn.expected_count(_FIELD[t], cal[world][t])
        cal["paper_table2"] = PAPER_TABLE2
        json.dump(cal, sys.stdout, indent=1)
        sys.stdout.write("\n")
        return cal
    out: dict[str, Any] = {
        "features_per_measurement": feature_counts(),
        "features_per_measurement_paper_world": feature_counts(similarity=0.8, world="paper"),
        "paper_table2": PAPER_TABLE2,
        "likeness": {str(s): office_likeness(s) for s in (0.0, 0.5, 0.8, 1.0)},
        "intensity": intensity_stats(),
    }
    json.dump(out, sys.stdout, indent=1)
    sys.stdout.write("\n")
    return out


if __name__ == "__main__":
    main()
