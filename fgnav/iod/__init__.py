"""Initial orbit determination: the orbit from the measurements alone, below the solvers.

One method per module, as Orekit's ``estimation/iod`` keeps them apart from its estimators:

- ``prior``       the log's own a-priori state propagated (the first guess with a prior)
- ``angles``      geocentric directions (+ ranges): plane, sessions, the Kepler angle fit,
                  Gibbs and Herrick-Gibbs
- ``surfaces``    one epoch's position surfaces intersected (geometric fixes)
- ``direct_fix``  closed-form single-epoch fixes (refraction cones, the Sun/Earth/Moon fix)
- ``geometric``   the orbit from geometric fixes along the pass (cones and tori: the cruise)
- ``fit``         the least squares they share (Levenberg-Marquardt, Gauss-Newton with step
                  halving, the 6-state fit on a pass's rows) and the ``InitialOrbit`` record
- ``initial``     the entry point: which method a pass supports, ``initial_orbit``
"""
