"""Named configurations of the place model, one per kind of sensor.

A *preset* is a plain dictionary of :class:`~fingerloc.model.PlaceModel`
arguments in JSON form (alignment costs by name: ``"unit"`` or
``"feature"``), plus the laser feature extractor's arguments. The entries of
:data:`PRESETS` are meant to be edited: change a value there and every
command, the benchmark and the library follow.

=============  ====================================================================
``paper``      the seed paper's program exactly: mixtures of VE, CP, Ex, B and the
               fingerprint string, unit alignment costs, ``1 / (cost + 1)``
``laser2d``    a 2D laser (no camera): fingerprint string with laser letters and
               the range term ``R``, feature-aware costs, cyclic matching,
               ``exp(-lambda cost)`` (the real-log benchmark's ``fingerprint``)
``panorama``   a panoramic camera: cyclic matching of the fingerprint string
               (vertical edges and colour patches), heading-free
``multimodal`` laser and camera: the string holds both sensors' letters, plus the
               range term; cyclic, feature-aware costs
``auto``       picks one of the above from the training observations
               (:func:`choose_preset`)
=============  ====================================================================
"""

from __future__ import annotations

import copy
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from ..errors import InvalidParameterError

if TYPE_CHECKING:
    from ..model import PlaceModel
    from ..observation import Observation

__all__ = [
    "COST_NAMES",
    "PRESETS",
    "PRESET_NAMES",
    "ResolvedPreset",
    "choose_preset",
    "empty_terms",
    "model_from_options",
    "model_options",
    "resolve_preset",
]

#: name -> {"description": str, "model": PlaceModel arguments (JSON form), "features": laser extractor arguments}.
PRESETS: dict[str, dict[str, Any]] = {
    "paper": {
        "description": "the seed paper's program: VE, CP, Ex, B mixtures and the fingerprint, unit costs",
        "model": {"terms": ["VE", "CP", "Ex", "B", "Fp"]},
        "features": {},
    },
    "laser2d": {
        "description": "2D laser: fingerprint with laser letters + range term, cyclic, feature-aware costs, exp",
        "model": {
            "terms": ["Fp", "R"],
            "laser_letters": True,
            "costs": "feature",
            "cyclic": True,
            "fp_likelihood": "exp",
        },
        "features": {},
    },
    "panorama": {
        "description": "panoramic camera: the appearance term A + the local-feature term K (SIFT matches verified "
        "by a relative pose), each calibrated leave-one-out, weight 1 each; K's verified rotation gives the heading, the aligned-profile term AP and the fingerprint string "
        "(matched over every rotation) its fallbacks, both with weight 0",
        "model": {
            "terms": ["Fp", "A", "AP", "K"],
            "cyclic": True,
            "costs": "feature",
            "fp_likelihood": "exp",
            "weights": {"Fp": 0.0, "A": 1.0, "AP": 0.0, "K": 1.0},
        },
        "features": {},
    },
    "multimodal": {
        "description": "laser and camera: one string with both sensors' letters + range term R + appearance "
        "term A, cyclic",
        "model": {
            "terms": ["Fp", "R", "A"],
            "laser_letters": True,
            "costs": "feature",
            "cyclic": True,
            "fp_likelihood": "exp",
        },
        "features": {},
    },
}

#: Every name ``--preset`` accepts.
PRESET_NAMES: tuple[str, ...] = (*PRESETS, "auto")
#: Names of alignment cost models in a preset's ``costs``.
COST_NAMES: tuple[str, ...] = ("unit", "feature")


@dataclass(frozen=True, slots=True)
class ResolvedPreset:
    """A preset after ``auto`` and explicit options are applied.

    Attributes
    ----------
    name : str
        The preset used (never ``"auto"``).
    requested : str
        The name asked for (``"auto"`` or ``name``).
    reason : str
        One line: why this preset (for ``auto``, what the data held).
    options : dict
        Every :class:`~fingerloc.model.PlaceModel` argument, JSON form (the
        model's defaults, then the preset's values, then the overrides).
    overrides : dict
        The explicit options that replaced a preset value.
    features : dict
        Arguments of the laser feature extractor.
    """

    name: str
    requested: str
    reason: str
    options: dict[str, Any]
    overrides: dict[str, Any] = field(default_factory=dict)
    features: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        """JSON-ready: ``{"name", "requested", "reason", "options", "overrides", "features"}``."""
        return {
            "name": self.name,
            "requested": self.requested,
            "reason": self.reason,
            "options": copy.deepcopy(self.options),
            "overrides": copy.deepcopy(self.overrides),
            "features": copy.deepcopy(self.features),
        }

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> ResolvedPreset:
        """Inverse of :meth:`to_json`."""
        try:
            return cls(
                name=str(data["name"]),
                requested=str(data.get("requested", data["name"])),
                reason=str(data.get("reason", "")),
                options=dict(data["options"]),
                overrides=dict(data.get("overrides", {})),
                features=dict(data.get("features", {})),
            )
        except (KeyError, TypeError, ValueError) as err:
            raise InvalidParameterError(f"invalid stored preset ({err})") from err

    def model(self) -> PlaceModel:
        """A fresh, unfitted :class:`~fingerloc.model.PlaceModel` with these options."""
        return model_from_options(self.options)


def _laser_and_image(observations: Sequence[Observation]) -> tuple[int, int]:
    laser = sum(
        1 for o in observations if o.c.size or o.ex.size or o.w.size or o.ranges is not None
    )
    image = sum(
        1
        for o in observations
        if o.ve.size or o.cp.size or o.appearance is not None or o.profile is not None or o.keypoints is not None
    )
    return laser, image


def choose_preset(observations: Sequence[Observation]) -> tuple[str, str]:
    """The preset ``auto`` picks for these training observations, and a one-line reason.

    Laser features only (corners, extremities, wall segments or a range
    profile, no vertical edge or colour patch) -> ``laser2d``; image features
    only (vertical edges, colour patches, or a camera's appearance
    descriptor, column profile or keypoints) -> ``panorama``; both ->
    ``multimodal``; neither -> ``paper``.
    """
    n = len(observations)
    laser, image = _laser_and_image(observations)
    if laser and image:
        return "multimodal", f"{laser} of {n} observations have laser features and {image} image features"
    if laser:
        return "laser2d", f"{laser} of {n} observations have laser features, none has image features"
    if image:
        return "panorama", f"{image} of {n} observations have image features, none has laser features"
    return "paper", f"none of {n} observations has laser or image features"


def empty_terms(options: Mapping[str, Any], observations: Sequence[Observation]) -> list[str]:
    """The mixture terms (VE, CP, Ex, B) among ``options["terms"]`` for which no observation has a bearing.

    Such a term is learned from nothing: every place gets the same flat
    density and the term cannot tell places apart (a 2D laser gives no VE
    or CP; beacons need remission values).
    """
    mog = ("VE", "CP", "Ex", "B")
    return [t for t in options.get("terms", ()) if t in mog and not any(o.bearings(t).size for o in observations)]


def _defaults() -> dict[str, Any]:
    from ..model import PlaceModel

    out = PlaceModel().get_params()
    out["costs"] = "unit"
    out["terms"] = list(out["terms"])
    return out


def resolve_preset(
    name: str, observations: Sequence[Observation] = (), overrides: Mapping[str, Any] | None = None
) -> ResolvedPreset:
    """Apply ``auto`` and explicit options: every PlaceModel argument, resolved.

    Parameters
    ----------
    name : str
        One of :data:`PRESET_NAMES`.
    observations : sequence of Observation
        The training observations (``auto`` looks at them).
    overrides : mapping, optional
        Explicit PlaceModel arguments (JSON form: ``costs`` as ``"unit"`` or
        ``"feature"``, ``terms`` a list); they win over the preset.

    Returns
    -------
    ResolvedPreset
    """
    if name not in PRESET_NAMES:
        raise InvalidParameterError(f"preset must be one of {', '.join(PRESET_NAMES)}, got {name!r}")
    if name == "auto":
        chosen, reason = choose_preset(observations)
        reason = f"auto picked {chosen}: {reason}"
    else:
        chosen, reason = name, f"preset {name} as asked"
    options = _defaults()
    options.update(copy.deepcopy(PRESETS[chosen]["model"]))
    given = {k: v for k, v in dict(overrides or {}).items() if v is not None}
    for k in given:
        if k not in options:
            raise InvalidParameterError(f"unknown model option {k!r} (known: {', '.join(options)})")
    if "terms" in given:
        given["terms"] = list(given["terms"])
    if "costs" in given and given["costs"] not in COST_NAMES:
        raise InvalidParameterError(f"costs must be one of {', '.join(COST_NAMES)}, got {given['costs']!r}")
    changed = {k: v for k, v in given.items() if options.get(k) != v}
    options.update(given)
    return ResolvedPreset(
        name=chosen,
        requested=name,
        reason=reason,
        options=options,
        overrides=changed,
        features=copy.deepcopy(PRESETS[chosen]["features"]),
    )


def model_options(name: str) -> dict[str, Any]:
    """The :class:`~fingerloc.model.PlaceModel` keyword arguments of a preset (``costs`` as an object).

    ``auto`` is not a configuration; resolve it with :func:`resolve_preset`.
    """
    if name not in PRESETS:
        raise InvalidParameterError(f"preset must be one of {', '.join(PRESETS)}, got {name!r}")
    return _to_model_kwargs({**_defaults(), **copy.deepcopy(PRESETS[name]["model"])})


def _to_model_kwargs(options: Mapping[str, Any]) -> dict[str, Any]:
    kw = dict(options)
    costs = kw.get("costs", "unit")
    if costs == "unit" or costs is None:
        kw["costs"] = None
    elif costs == "feature":
        from ..align import CostModel

        kw["costs"] = CostModel.feature_aware()
    elif isinstance(costs, str):
        raise InvalidParameterError(f"costs must be one of {', '.join(COST_NAMES)}, got {costs!r}")
    kw["terms"] = tuple(kw.get("terms", ()))
    return kw


def model_from_options(options: Mapping[str, Any]) -> PlaceModel:
    """A fresh :class:`~fingerloc.model.PlaceModel` from resolved options (JSON form)."""
    from ..model import PlaceModel

    return PlaceModel(**_to_model_kwargs(options))
