"""Variants of the appearance descriptor on a folder of 360 deg campus photos (development set, issue 14).

Usage::

    python scripts/appearance_variants.py PHOTO_DIR AREAS_DIR BAND_CACHE_DIR [--perturb]

PHOTO_DIR and AREAS_DIR are those of ``fingerloc bench panorama``. Each photo
is decoded once (the band -45..+45 deg at 1440 columns, as the bench reads
it) into BAND_CACHE_DIR as ``.npy`` (about 6 MB a photo: keep it out of the
repository, the photos have no licence). For each variant of
:func:`fingerloc.features.vision.appearance_descriptor`, every photo whose
place has two or more is a query against all the others; the answer is the
place of the nearest photo by L1 distance (what the term ``A`` ranks; its
``lambda`` does not change the order). Places by area and by map position, as
in the bench. Prints top-1 / mean rank (ties counted against).

With ``--perturb``, each query photo is also given a seeded random white
balance (each channel x exp(U(-0.2, 0.2))), exposure (x exp(U(-0.5, 0.5)),
clipped) and tone curve (power exp(U(-0.15, 0.15))), the references left as
they are: the lighting, white balance and exposure changes between two shots
of one room.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np
from scipy.spatial.distance import cdist

from fingerloc.experiments.panorama import (
    hsv_histogram,
    jeffrey_divergence,
    load_photo_band,
    load_tour_layout,
    places_by_area,
    places_by_position,
)
from fingerloc.features.vision import AppearanceParams, appearance_descriptor
from fingerloc.metrics import min_per_place, true_place_ranks
from fingerloc.sensors import Panorama

V1 = {"strips": 1, "gradients": False, "harmonics": 12}
#: name -> (appearance_descriptor parameters, "sqrt" (as stored) or "shares" (squared back: L1 on the shares))
VARIANTS: dict[str, tuple[dict[str, object], str]] = {
    "version-1 layout (1 strip, no gradients, 12 harmonics), shares": (V1, "shares"),
    "1 strip, no gradients, no layout, square roots": ({"strips": 1, "gradients": False}, "sqrt"),
    "3 strips, no gradients, square roots": ({"gradients": False}, "sqrt"),
    "3 strips + gradients, shares": ({}, "shares"),
    "3 strips + gradients, square roots (version 2, default)": ({}, "sqrt"),
    "2 strips + gradients, square roots": ({"strips": 2}, "sqrt"),
    "4 strips + gradients, square roots": ({"strips": 4}, "sqrt"),
    "6 strips + gradients, square roots": ({"strips": 6}, "sqrt"),
    "default + layout (12 harmonics)": ({"harmonics": 12}, "sqrt"),
    "default, no white balance": ({"white_balance": False}, "sqrt"),
    "default, 24 hue bins": ({"hue_bins": 24}, "sqrt"),
}


def _shares(d: np.ndarray, kw: dict[str, object]) -> np.ndarray:
    """The shares back from the square roots (the layout block, not square-rooted, stays)."""
    p = AppearanceParams(**kw)  # type: ignore[arg-type]
    n = p.strips * p.strip_size
    return np.r_[d[:n] ** 2, d[n:]]


def _perturb(img: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    gains = np.exp(rng.uniform(-0.2, 0.2, 3))
    expo = np.exp(rng.uniform(-0.5, 0.5))
    gamma = np.exp(rng.uniform(-0.15, 0.15))
    return np.clip((img * gains * expo) ** gamma, 0.0, 1.0).astype(np.float32)


def _top1(d: np.ndarray, labels: list[str | None]) -> tuple[float, float]:
    idx = [i for i, lab in enumerate(labels) if lab is not None]
    sub = [str(labels[i]) for i in idx]
    classes = sorted(set(sub))
    owner = np.array([classes.index(lab) for lab in sub])
    counts = np.bincount(owner)
    q = [k for k in range(len(idx)) if counts[owner[k]] >= 2]
    dd = d[np.ix_(idx, idx)].copy()
    np.fill_diagonal(dd, np.inf)
    r = true_place_ranks(-min_per_place(dd[q], owner, len(classes)), owner[q])
    return float(np.mean(r == 1)), float(np.mean(r))


def main(photo_dir: str, areas_dir: str, band_dir: str, *flags: str) -> None:
    photos = load_tour_layout(areas_dir)
    cache = Path(band_dir)
    cache.mkdir(parents=True, exist_ok=True)
    keep, bands = [], []
    for i, p in enumerate(photos):
        f = cache / (p.file.replace("/", "__") + ".npy")
        if not f.exists():
            if not (Path(photo_dir) / p.file).is_file():
                continue
            np.save(f, load_photo_band(Path(photo_dir) / p.file).image)
        keep.append(i)
        bands.append(f)
    defs = {
        "area": [places_by_area(photos)[i] for i in keep],
        "position": [places_by_position(photos)[i] for i in keep],
    }
    perturb = "--perturb" in flags

    def line(name: str, d: np.ndarray, dp: np.ndarray | None, t0: float) -> None:
        out = f"{name:58s}"
        for lab in defs.values():
            a = _top1(d, lab)
            out += f" | {a[0]:.3f} / {a[1]:5.2f}"
        if dp is not None:
            for lab in defs.values():
                a = _top1(dp, lab)
                out += f" | {a[0]:.3f} / {a[1]:5.2f}"
        print(out + f"  ({time.time() - t0:.0f} s)", flush=True)

    head = "variant (A alone, nearest photo)" + " " * 26 + " | by area        | by position"
    print(head + (" | perturbed: area | perturbed: position" if perturb else ""))
    t0 = time.time()
    hc, hp = [], []
    for k, f in enumerate(bands):
        img = np.load(f)
        hc.append(hsv_histogram(img))
        if perturb:
            hp.append(hsv_histogram(_perturb(img, np.random.default_rng(k))))
    h = np.stack(hc)
    line("HSV histograms + Jeffrey (baseline)", jeffrey_divergence(h, h),
         jeffrey_divergence(np.stack(hp), h) if perturb else None, t0)
    for name, (kw, form) in VARIANTS.items():
        t0 = time.time()
        clean, pert = [], []
        for k, f in enumerate(bands):
            img = np.load(f)
            d = appearance_descriptor(Panorama(img), **kw)
            clean.append(d if form == "sqrt" else _shares(d, kw))
            if perturb:
                dq = appearance_descriptor(Panorama(_perturb(img, np.random.default_rng(k))), **kw)
                pert.append(dq if form == "sqrt" else _shares(dq, kw))
        c = np.stack(clean)
        line(name, cdist(c, c, "cityblock"), cdist(np.stack(pert), c, "cityblock") if perturb else None, t0)


if __name__ == "__main__":
    main(*sys.argv[1:])
