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

__all__ = ["without_aberration", "with_aberration", "aberration_off"]


def _switched(families: dict, on: bool) -> dict:
    out = {}
    for kind, fam in families.items():
        if "aberration" in fam.values:
            values = dict(fam.values)
            values["aberration"] = np.full(len(fam), on, bool)
            fam = dataclasses.replace(fam, values=values)
        out[kind] = fam
    return out


def _off(families: dict) -> dict:
    return _switched(families, False)


def without_aberration(p):
    """The :class:`fgnav.measurements.Pass` ``p`` with the aberration correction off in
    every family that has one (solved and deferred rows); other rows unchanged."""
    return dataclasses.replace(p, families=_off(p.families), deferred=_off(p.deferred))


def with_aberration(p):
    """The pass ``p`` with the aberration correction on in every family that has one: what
    the rows of a ``--no-aberration`` solve would be with the physics (the integrity
    verdict's consider analysis, :func:`fgnav.diagnostics.integrity.aberration_sensitivity`)."""
    return dataclasses.replace(p, families=_switched(p.families, True),
                               deferred=_switched(p.deferred, True))


def aberration_off(p) -> list[str]:
    """The kinds of pass ``p`` whose rows all take their directions without the correction."""
    return [kind for kind, fam in p.families.items()
            if "aberration" in fam.values and len(fam) and not np.any(fam.values["aberration"])]
