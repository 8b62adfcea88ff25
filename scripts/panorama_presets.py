"""Leave-one-out top-1 of PlaceModel configurations on a folder of 360 deg campus photos (development set).

Usage::

    python scripts/panorama_presets.py PHOTO_DIR AREAS_DIR CACHE.jsonl [NAME,NAME,...]

PHOTO_DIR, AREAS_DIR and the cache are those of ``fingerloc bench panorama``
(the cache holds the extracted features). Each photo whose place has two or
more photos is a query against a model fit on every other photo; places are
defined by area and by map position (fingerloc.experiments.panorama). Prints
one line per (definition, configuration). Slow (one fit per query).
"""

import sys
import time

from fingerloc.align import CostModel
from fingerloc.experiments.panorama import extract_features, load_tour_layout, places_by_area, places_by_position
from fingerloc.model import PlaceModel

FEATURE = CostModel.feature_aware()
CONFIGS = {
    "Fp+A (cyclic, feature, exp)": dict(terms=("Fp", "A"), cyclic=True, costs=FEATURE, fp_likelihood="exp"),
    "A": dict(terms=("A",)),
    "Fp+A weights=fit (former preset)": dict(
        terms=("Fp", "A"), cyclic=True, costs=FEATURE, fp_likelihood="exp", weights="fit"
    ),
    "AP": dict(terms=("AP",)),
    "A+AP": dict(terms=("A", "AP")),
    "A+AP weights=fit": dict(terms=("A", "AP"), weights="fit"),
    "Fp+A+AP weights=fit (former preset)": dict(
        terms=("Fp", "A", "AP"), cyclic=True, costs=FEATURE, fp_likelihood="exp", weights="fit"
    ),
    "K": dict(terms=("K",)),
    "A+K weights=fit": dict(terms=("A", "K"), weights="fit"),
    "A+K": dict(terms=("A", "K")),
    "Fp+A+AP+K weights A=K=1 Fp=AP=0": dict(
        terms=("Fp", "A", "AP", "K"), cyclic=True, costs=FEATURE, fp_likelihood="exp",
        weights={"Fp": 0.0, "A": 1.0, "AP": 0.0, "K": 1.0},
    ),
    "Fp+A+AP+K weights=fit (panorama preset)": dict(
        terms=("Fp", "A", "AP", "K"), cyclic=True, costs=FEATURE, fp_likelihood="exp", weights="fit"
    ),
    "VE+CP+Fp+A rotate, fit": dict(
        terms=("VE", "CP", "Fp", "A"), cyclic=True, costs=FEATURE, fp_likelihood="exp", weights="fit",
        rotate_mixtures=True, n_components=3,
    ),
    "VE+CP+Fp+A rotate": dict(
        terms=("VE", "CP", "Fp", "A"), cyclic=True, costs=FEATURE, fp_likelihood="exp", rotate_mixtures=True,
        n_components=3,
    ),
}


def main(photo_dir: str, areas_dir: str, cache: str, only: str = "") -> None:
    photos = load_tour_layout(areas_dir)
    feats = extract_features(photo_dir, photos, cache=cache)
    for defn, labs in (("area", places_by_area(photos)), ("position", places_by_position(photos))):
        idx = [i for i, f in enumerate(feats) if f is not None and labs[i] is not None]
        obs = [feats[i].observation.with_label(labs[i]) for i in idx]
        lab = [labs[i] for i in idx]
        queries = [k for k in range(len(obs)) if lab.count(lab[k]) >= 2]
        for name, cfg in CONFIGS.items():
            if only and name not in only.split(","):
                continue
            t0 = time.time()
            hits = 0
            for k in queries:
                m = PlaceModel(**cfg).fit([o for j, o in enumerate(obs) if j != k])
                hits += int(m.predict([obs[k]])[0] == lab[k])
            print(f"{defn:8s} {name:36s} top1 {hits / len(queries):.3f} ({hits}/{len(queries)}) {time.time() - t0:.0f}s")


if __name__ == "__main__":
    main(*sys.argv[1:5])
