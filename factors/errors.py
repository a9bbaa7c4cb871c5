"""Errors of the measurement and motion models."""


class ModelDomainError(ValueError):
    """A state outside the domain of a measurement model, e.g. a position inside the limb
    sphere, where no limb is seen. Raised during linearization; solvers turn it into a
    message that the estimate left the model's domain (a first guess far off). ``row``: the
    index of the offending row among those evaluated, where the model knows it."""

    def __init__(self, message: str, row: int | None = None):
        super().__init__(message)
        self.row = row


class EphemerisSpanError(ValueError):
    """An epoch outside the span of a planetary ephemeris (ERFA's series: 1900-2100)."""
