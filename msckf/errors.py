"""Errors of the msckf library."""


class MsckfInputError(ValueError):
    """Bad input to the VIO (config values, array shapes, non-monotonic stamps). Shown to users without traceback."""


class FilterDivergedError(RuntimeError):
    """The filter diverged (NaN/inf state, covariance not positive definite, absurd velocity).

    A run that raises this is recorded as failed with ``reason``; it is never hidden.
    """

    def __init__(self, reason: str, stamp_s: float | None = None) -> None:
        self.reason = reason
        self.stamp_s = stamp_s
        where = f" at t={stamp_s:.3f} s" if stamp_s is not None else ""
        super().__init__(f"filter diverged{where}: {reason}")
