"""The measurement models of ``fgnav``, assembled (see :mod:`fgnav.models.model`).

Each kind is defined in one module of this package, by family: :mod:`~fgnav.models.priors`,
:mod:`~fgnav.models.directions`, :mod:`~fgnav.models.ranges`, :mod:`~fgnav.models.refraction`,
:mod:`~fgnav.models.attitude`, :mod:`~fgnav.models.body_directions`, :mod:`~fgnav.models.gyro`,
:mod:`~fgnav.models.stars`, :mod:`~fgnav.models.angles`, :mod:`~fgnav.models.isl`,
:mod:`~fgnav.models.near_body`, :mod:`~fgnav.models.manoeuvres` (declared manoeuvres: no
measurement model, a log schema row); each lists its
models in ``MEASUREMENT_MODELS`` and may define the log schema rows of kinds the CSV format
does not list (``LOG_KINDS``, :class:`fgnav.io.log_csv.KindSpec`). This module only assembles
them: :data:`MODELS`, :data:`VARIABLES`, :data:`LOG_SCHEMA`, and re-exports every model and
variable by name, so that ``from fgnav.models.registry import EARTH_DIRECTION`` keeps working.
The solvers, the EKFs, the initial-orbit code and the visualization iterate over
:data:`MODELS` or ask :func:`model`. To add a measurement: CONTRIBUTING.md, "Add a
measurement".
"""

from __future__ import annotations

from fgnav.errors import UserError
from fgnav.io.log_csv import FORMAT_KINDS, KindSpec
from fgnav.models import (angles, attitude, body_directions, directions, gyro, isl,
                          manoeuvres, near_body, priors, ranges, refraction, stars)
from fgnav.models.angles import BODY_BODY_ANGLE, BODY_STAR_ANGLE, LIMB_STAR_ANGLE
from fgnav.models.attitude import ATTITUDE, ATTITUDE_RATE, ATTITUDE_VARIABLE
from fgnav.models.body_directions import (EARTH_DIRECTION_BODY, MOON_DIRECTION_BODY,
                                          SUN_DIRECTION_BODY)
from fgnav.models.directions import EARTH_DIRECTION
from fgnav.models.gyro import GYRO, GYRO_BIAS
from fgnav.models.isl import ISL_CARRIER_PHASE, ISL_PSEUDORANGE
from fgnav.models.model import MeasurementModel
from fgnav.models.near_body import BODY_DIRECTION, BODY_DIRECTION_BODY
from fgnav.models.priors import PRIOR_POSITION, PRIOR_VELOCITY
from fgnav.models.ranges import ALTITUDE, LIMB_RADIUS
from fgnav.models.refraction import REFRACTION, REFRACTION_BIAS, refraction_ray_eci
from fgnav.models.stars import CAMERA_ALIGNMENT, STAR_DIRECTION_BODY
from fgnav.models.variables import ORBIT, Variable

__all__ = ["MODELS", "VARIABLES", "LOG_SCHEMA", "FAMILY_MODULES", "MOTION_KINDS", "model", "solved_models",
           "prior_kinds", "eci_ray_kinds", "variable", "REFRACTION_BIAS", "ATTITUDE",
           "ATTITUDE_VARIABLE", "PRIOR_POSITION", "PRIOR_VELOCITY", "EARTH_DIRECTION",
           "LIMB_RADIUS", "ALTITUDE", "REFRACTION", "EARTH_DIRECTION_BODY", "SUN_DIRECTION_BODY",
           "MOON_DIRECTION_BODY", "GYRO", "GYRO_BIAS", "STAR_DIRECTION_BODY", "BODY_STAR_ANGLE",
           "LIMB_STAR_ANGLE", "BODY_BODY_ANGLE", "CAMERA_ALIGNMENT", "ATTITUDE_RATE",
           "refraction_ray_eci", "ISL_PSEUDORANGE", "ISL_CARRIER_PHASE", "BODY_DIRECTION",
           "BODY_DIRECTION_BODY"]

FAMILY_MODULES = (priors, directions, ranges, refraction, attitude, body_directions, gyro, stars,
                  angles, isl, near_body, manoeuvres)
"""The modules that define the kinds, in the order of :data:`MODELS`."""

MODELS: dict[str, MeasurementModel] = {
    m.kind: m for mod in FAMILY_MODULES for m in mod.MEASUREMENT_MODELS}
"""Every log kind the project reads, by kind."""

LOG_SCHEMA: dict[str, KindSpec] = {**FORMAT_KINDS, **{
    k: spec for mod in FAMILY_MODULES for k, spec in getattr(mod, "LOG_KINDS", {}).items()}}
"""The log schema of every kind (``{kind: KindSpec}``): the CSV format's own kinds
(:data:`fgnav.io.log_csv.FORMAT_KINDS`) and those a family module adds; the callers above
this layer pass it to the readers and writers (``read_log(path, schema=LOG_SCHEMA)``)."""

MOTION_KINDS: tuple[str, ...] = tuple(
    k for mod in FAMILY_MODULES for k in getattr(mod, "MOTION_KINDS", ()))
"""The log kinds that are no measurement but enter the motion (a declared manoeuvre,
:mod:`fgnav.models.manoeuvres`): in :data:`LOG_SCHEMA`, not in :data:`MODELS`."""

VARIABLES: dict[str, Variable] = {ORBIT.name: ORBIT, **{
    v.name: v for m in MODELS.values() for v in m.optional_variables}}
VARIABLES[ATTITUDE_RATE.name] = ATTITUDE_RATE
"""Every graph variable a model declares, by name (the orbit state first), and the attitude's
rate (its process model's variable)."""


def model(kind: str) -> MeasurementModel:
    """The model of a log kind (KeyError for a kind the registry does not know)."""
    return MODELS[kind]


def solved_models(kinds) -> list[MeasurementModel]:
    """The models among ``kinds`` that enter the graphs, in the given order."""
    return [MODELS[k] for k in kinds if k in MODELS and MODELS[k].solved]


def prior_kinds() -> tuple[str, ...]:
    return tuple(k for k, m in MODELS.items() if m.prior)


def eci_ray_kinds() -> tuple[str, ...]:
    """Kinds whose x, y, z is a unit direction in ECI (drawn as rays)."""
    return tuple(k for k, m in MODELS.items() if m.eci_ray)



def variable(name: str) -> Variable:
    """A declared variable by name (dashes allowed, as on the command line)."""
    key = str(name).replace("-", "_")
    if key not in VARIABLES or key == ORBIT.name:
        raise UserError(f"--estimate: unknown variable '{name}'; variables that can be "
                        f"estimated: {', '.join(v.cli_name for v in VARIABLES.values() if v is not ORBIT)}")
    return VARIABLES[key]
