"""One exception hierarchy for the whole package.

The CLI maps :class:`InvalidParameter` (bad user input: a campaign file, a rig file, a CLI flag,
a differentiator design) to exit code 2 and every other :class:`LabrunnerError` to exit code 1.
"""

from __future__ import annotations


class LabrunnerError(Exception):
    """Base class of every error labrunner raises on purpose."""


class InvalidParameter(LabrunnerError, ValueError):
    """A parameter is outside its allowed range; the message names the field and the range.

    ``field`` is the parameter's name or dotted key path (e.g. ``"differentiator.alpha"``).
    """

    def __init__(self, field: str, message: str) -> None:
        self.field = field
        self.message = message
        super().__init__(f"{field}: {message}")

    def __reduce__(self) -> tuple[type, tuple[str, str]]:
        """Pickle by (field, message): the error crosses process pools and Dask workers intact."""
        return (type(self), (self.field, self.message))


class RigError(LabrunnerError):
    """The rig or its transport is unhealthy (device gone, bus off, watchdog): stop the campaign."""


class CampaignError(LabrunnerError):
    """A campaign cannot proceed (directory locked, file edited since planning, ...)."""


def check_finite(field: str, value: float) -> float:
    """Return ``float(value)`` or raise :class:`InvalidParameter` for NaN/inf/non-numbers."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise InvalidParameter(field, f"must be a number, got {value!r}") from None
    if v != v or v in (float("inf"), float("-inf")):
        raise InvalidParameter(field, f"must be finite, got {value!r}")
    return v
