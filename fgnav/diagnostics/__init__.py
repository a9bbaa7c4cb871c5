"""Diagnostics of a pass and of a solution, below the solvers and the pipeline.

- ``crb``            the Cramer-Rao bound of a pass (the linearization along an orbit,
                     eliminated), its observability check and cumulative STMs
- ``consistency``    NEES / NIS / ANEES and their chi-square bands
- ``observability``  the observability matrix over a window, its weakest directions
- ``integrity``      the verdict on a solution: chi-squares, residual runs, manoeuvre test,
                     omitted-force analysis (summary.json "integrity")
- ``mirror``         a formation's mirrored relative geometry solved again and compared

Nothing here imports the solvers (the mirror test is given the batch smoother), the start policy or the pipeline: the gap planning of the
solvers (:mod:`fgnav.solvers.arcs`) and the pipeline's summary both call down into it.
"""
