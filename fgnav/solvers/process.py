"""The process model of the graph variables beyond the orbit state (its earlier home).

The rows and the GTSAM factors of every variable's process are built in :mod:`fgnav.graph`
(:func:`fgnav.graph.process_rows`, :func:`fgnav.graph.process_factors`), driven by each
variable's ``process`` object (:mod:`fgnav.models.variables`: a random walk ``b_{k+1} = b_k +
w``, ``w ~ N(0, psd dt I)``, Maybeck 1979, vol. 1, sec. 4.10, or a rate's constant-rate
motion of the rotation it turns, ``factors.attitude_motion``). The names here stay for the
code that imports them.
"""

from __future__ import annotations

from fgnav.graph import process_rows

__all__ = ["variable_step_rows", "constant_rate"]

variable_step_rows = process_rows


def constant_rate(lay) -> bool:
    """True when a process of the layout writes two variables jointly (a rate turning its
    rotation: the attitude's constant-rate motion)."""
    return any(len(names) > 1 for _, names in lay.groups)
