"""Measurement models and graph variables: one object per log kind, each kind in one module.

* :mod:`fgnav.models.variables` — graph variables (:class:`Variable`) and a pass's per-epoch
  block of them (:class:`Layout`);
* :mod:`fgnav.models.model` — :class:`MeasurementModel`, what one kind provides;
* one module per family of kinds — :mod:`~fgnav.models.priors`, :mod:`~fgnav.models.directions`,
  :mod:`~fgnav.models.ranges`, :mod:`~fgnav.models.refraction`, :mod:`~fgnav.models.attitude`,
  :mod:`~fgnav.models.body_directions`, :mod:`~fgnav.models.gyro`, :mod:`~fgnav.models.stars`,
  :mod:`~fgnav.models.angles`, :mod:`~fgnav.models.isl` (helpers: :mod:`~fgnav.models.values`,
  :mod:`~fgnav.models.bodies`);
* :mod:`fgnav.models.registry` — the assembly (:data:`MODELS`, :data:`VARIABLES`,
  :data:`LOG_SCHEMA`) and lookups.
"""
