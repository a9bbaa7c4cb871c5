"""Measurement models and graph variables: one object per log kind, registered once.

* :mod:`fgnav.models.variables` — graph variables (:class:`Variable`) and a pass's per-epoch
  block of them (:class:`Layout`);
* :mod:`fgnav.models.model` — :class:`MeasurementModel`, what one kind provides;
* :mod:`fgnav.models.registry` — the entries (:data:`MODELS`) and lookups.
"""
