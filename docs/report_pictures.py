"""Make the README's pictures of the four reports.

    python docs/report_pictures.py WORK_DIR [CARMEN_LOG]

Writes, under WORK_DIR, a localize and a track report of simulated offices
(ground-truth features with 4 deg bearing noise, through the real ``learn``,
``localize --report`` and ``track --report`` commands), a panorama report of a
rendered panorama against a reference view taken with another heading, and,
with a CARMEN log, the map report of ``bench carmen --report`` and the track
report of ``track LOG --map --report`` (the README's track picture). Then headless
Chromium takes a screenshot of the top of each page, saved small into
``docs/report-*.png``.
"""

from __future__ import annotations

import math
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
from PIL import Image

from fingerloc.align import cyclic_alignment
from fingerloc.cli import main
from fingerloc.features.vision import extract_vision_features, observation_from_views
from fingerloc.fingerprint import make_fingerprint
from fingerloc.io.jsonl import write_observations
from fingerloc.observation import Observation
from fingerloc.reporting import write_panorama_report
from fingerloc.sim import make_offices, protocol_poses, render_panorama, true_observation

DOCS = Path(__file__).resolve().parent


def _run(*args: object) -> None:
    try:
        main([str(a) for a in args])
    except SystemExit as e:
        if e.code:
            raise


def _noisy(o: Observation, rng: np.random.Generator, sigma_deg: float = 4.0) -> Observation:
    s = math.radians(sigma_deg)
    return Observation(
        ve=o.ve + rng.normal(0, s, o.ve.size), cp=o.cp + rng.normal(0, s, o.cp.size), cp_hue=o.cp_hue,
        ex=o.ex + rng.normal(0, s, o.ex.size), c=o.c + rng.normal(0, s, o.c.size), b=o.b,
        label=o.label, pose=o.pose,
    )  # fmt: skip


def simulated_session(work: Path) -> None:
    rng = np.random.default_rng(0)
    worlds = make_offices(10, similarity=0.8, random_state=1)
    train, test = [], []
    for k, w in enumerate(worlds):
        tr, te = protocol_poses(w, n_train=8, n_test=6, random_state=k)
        shift = np.array([2.5 * k, 0.0, 0.0])  # offices side by side along a corridor, for the trajectory
        train += [_noisy(true_observation(w, tuple(p), label=w.name), rng) for p in tr]
        test += [_noisy(true_observation(w, tuple(p), label=w.name), rng) for p in te]
        for lst in (train, test):
            n = len(tr) if lst is train else len(te)
            for i in range(len(lst) - n, len(lst)):
                o = lst[i]
                assert o.pose is not None
                lst[i] = Observation(ve=o.ve, cp=o.cp, cp_hue=o.cp_hue, ex=o.ex, c=o.c, b=o.b, label=o.label,
                                     pose=tuple(np.asarray(o.pose) + shift))  # fmt: skip
    write_observations(work / "train.jsonl", train)
    write_observations(work / "test.jsonl", test)
    db = work / "offices.sqlite"
    db.unlink(missing_ok=True)
    _run("learn", work / "train.jsonl", "--db", db, "-k", "3", "--terms", "VE,Ex,Fp")
    _run("localize", work / "test.jsonl", "--db", db, "--quiet", "--report", work / "localize")
    # a run: the test views in office order, then a jump back to the first offices (a kidnapping)
    run = test + test[: 6 * 4]
    write_observations(work / "run.jsonl", run)
    _run(
        "track", work / "run.jsonl", "--db", db, "--graph-from", work / "train.jsonl", "-q", "--report", work / "track"
    )


def panorama(work: Path) -> None:
    w = make_offices(1, random_state=3)[0]
    x, y = w.anchor
    ref = render_panorama(w, (x, y, 0.0), random_state=0)
    now = render_panorama(w, (x + 0.2, y + 0.1, math.radians(40.0)), random_state=1)
    fr, fn = extract_vision_features(ref), extract_vision_features(now)
    q = make_fingerprint(observation_from_views(panorama=now))
    r = make_fingerprint(observation_from_views(panorama=ref))
    h = cyclic_alignment(q, r).heading_deg
    write_panorama_report(
        work / "panorama", now.image, edges=fn.edges, patches=fn.patches, patch_hues_deg=fn.patch_hues,
        bearing_offset=now.bearing_offset, clockwise=now.clockwise, reference_image=ref.image,
        reference_edges=fr.edges, reference_patches=fr.patches, reference_hues_deg=fr.patch_hues,
        heading=None if h is None else math.radians(h),
        notes=["A simulated office; the robot turned 40 deg to the left (and moved 22 cm) since the reference view."],
    )  # fmt: skip


def screenshot(index: Path, out: Path, *, height: int = 1500, width: int = 1100) -> None:
    shot = Path(tempfile.mkdtemp()) / "shot.png"
    subprocess.run(
        ["/usr/bin/chromium", "--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
         "--disable-component-update", "--disable-sync", "--no-first-run", f"--user-data-dir={shot.parent / 'p'}",
         f"--window-size={width},{height}", "--hide-scrollbars", f"--screenshot={shot}", index.resolve().as_uri()],
        check=True, capture_output=True, timeout=120,
    )  # fmt: skip
    im = Image.open(shot).convert("RGB")
    im = im.resize((im.width * 3 // 5, im.height * 3 // 5), Image.Resampling.LANCZOS)
    im.quantize(256, method=Image.Quantize.FASTOCTREE).save(out, optimize=True)
    print(f"wrote {out} ({out.stat().st_size // 1024} kB)")


if __name__ == "__main__":
    work = Path(sys.argv[1])
    work.mkdir(parents=True, exist_ok=True)
    simulated_session(work)
    panorama(work)
    if len(sys.argv) > 2:
        _run("bench", "carmen", sys.argv[2], "-m", "fingerprint", "--report", work / "carmen")
        screenshot(work / "carmen" / "log1" / "map" / "index.html", DOCS / "report-map.png")
        db = work / "log.sqlite"
        db.unlink(missing_ok=True)
        _run("track", sys.argv[2], "--db", db, "--map", "-q", "--report", work / "track-log")
    screenshot(work / "localize" / "index.html", DOCS / "report-localize.png", height=2600)
    track = work / ("track-log" if len(sys.argv) > 2 else "track")
    screenshot(track / "index.html", DOCS / "report-track.png", height=1700)
    screenshot(work / "panorama" / "index.html", DOCS / "report-panorama.png", height=1000)
