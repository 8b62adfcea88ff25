"""The terms of the Bayesian program (docs/METHOD.md §4): one factor ``P(term | Loc)`` each.

=====  ==========================================================  ============
name   term                                                        class
=====  ==========================================================  ============
VE     vertical edges: product of angular mixtures                 MixtureTerm
CP     colour patches: product of angular mixtures                 MixtureTerm
Ex     laser extremities: product of angular mixtures              MixtureTerm
B      beacons: product of angular mixtures                        MixtureTerm
Fp     the fingerprint string: alignment to stored fingerprints   FingerprintTerm
R      range distribution (2D laser, heading-free; ours)           RangeTerm
A      appearance of the whole view (camera, heading-free; ours)  AppearanceTerm
AP     the view bearing by bearing, over every rotation (ours)     ProfileTerm
K      local features: keypoints matched to the best view (ours)    KeypointTerm
=====  ==========================================================  ============

:class:`fingerloc.model.PlaceModel` combines them; each term can also be used
on its own (``term.fit(groups).log_likelihood(observations)``).
"""

from .appearance import AppearanceTerm
from .base import Term
from .distance import DistanceTerm, fit_lambda
from .fingerprint import FingerprintTerm, consensus_fingerprint, crop_fingerprint
from .keypoints import KeypointTerm
from .mixture import LOG_UNIFORM, MOG_TERMS, MixtureTerm, fit_mixture_terms
from .profile import ProfileTerm, profile_peaks
from .range import RangeTerm, range_descriptor

__all__ = [
    "LOG_UNIFORM",
    "MOG_TERMS",
    "AppearanceTerm",
    "DistanceTerm",
    "FingerprintTerm",
    "KeypointTerm",
    "MixtureTerm",
    "ProfileTerm",
    "RangeTerm",
    "Term",
    "consensus_fingerprint",
    "crop_fingerprint",
    "fit_lambda",
    "fit_mixture_terms",
    "profile_peaks",
    "range_descriptor",
]
