"""Switch the stellar-aberration correction of a pass's star rows off (for comparison).

The star models (``star_direction_body``, ``refraction``) compare their rows with the
apparent direction of the star, the catalogue direction aberrated by the observer's velocity
(``factors.aberration``; Urban & Seidelmann 2013, eq. 7.40); the angle models
(``body_star_angle``, ``limb_star_angle``, ``body_body_angle``) measure between apparent
lines of sight (``factors.celestial_angles``). :func:`without_aberration` gives the same
pass with every such row taking the catalogue and geometric directions as seen, as a model
without the correction would: ``fgnav smooth --no-aberration`` and the tests that measure
what the correction is worth (README, "Apparent star directions").
"""

from __future__ import annotations

import dataclasses

import numpy as np

__all__ = ["without_aberration"]


def _off(families: dict) -> dict:
    out = {}
    for kind, fam in families.items():
        if "aberration" in fam.values:
            values = dict(fam.values)
            values["aberration"] = np.zeros(len(fam), bool)
            fam = dataclasses.replace(fam, values=values)
        out[kind] = fam
    return out


def without_aberration(p):
    """The :class:`fgnav.measurements.Pass` ``p`` with the aberration correction off in
    every family that has one (solved and deferred rows); other rows unchanged."""
    return dataclasses.replace(p, families=_off(p.families), deferred=_off(p.deferred))
