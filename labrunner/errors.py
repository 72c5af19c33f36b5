"""One exception hierarchy for the whole package.

The CLI maps :class:`InvalidParameter` (bad user input: a campaign file, a rig file, a CLI flag,
a differentiator design) to exit code 2 and every other :class:`LabrunnerError` to exit code 1.
"""

from __future__ import annotations

import errno


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
    """The rig or its transport is unhealthy (device gone, bus off, watchdog): the run fails; the
    campaign stops unless the rig shows it is back in its safe state (``RemoteRig.recover``)."""


class CampaignError(LabrunnerError):
    """A campaign cannot proceed (directory locked, file edited since planning, ...)."""


def check_finite(field: str, value: float, allowed: str | None = None) -> float:
    """Return ``float(value)`` or raise :class:`InvalidParameter` for NaN/inf/non-numbers.

    ``allowed`` (e.g. ``"a finite number > -1"``) states the range the caller checks next; the
    message then reads "must be <allowed>", so a NaN is told the same range as any bad value.
    """
    try:
        if isinstance(value, bool):  # float(True) == 1.0: a TOML `true` is not a number
            raise TypeError
        v = float(value)
    except (TypeError, ValueError):
        raise InvalidParameter(field, f"must be {allowed or 'a number'}, got {value!r}") from None
    if v != v or v in (float("inf"), float("-inf")):
        raise InvalidParameter(field, f"must be {allowed or 'finite'}, got {value!r}")
    return v


def check_number(field: str, value: object) -> float:
    """Return a finite ``int``/``float`` as ``float``; reject booleans, strings and NaN/inf.

    Stricter than :func:`check_finite` (which converts ``"3"``): for values read from TOML, where a
    quoted number or ``true`` is a mistake to report, not to convert.
    """
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise InvalidParameter(field, f"must be a number, got {value!r}")
    return check_finite(field, value)


def check_positive(field: str, value: float, *, strict: bool = False) -> float:
    """Return ``float(value)`` or raise :class:`InvalidParameter` unless it is finite and > 0.

    ``strict``: the value must already be a number (see :func:`check_number`), as in a file.
    """
    v = check_number(field, value) if strict else check_finite(field, value, "a finite number > 0")
    if v <= 0.0:
        raise InvalidParameter(field, f"must be > 0, got {value!r}")
    return v


def check_interval(field: str, value: object, *, what: str = "[lo, hi]", empty: bool = False) -> tuple[float, float]:
    """Return ``(lo, hi)`` from a two-number list or tuple with finite ``lo < hi``.

    ``what`` names the form in the message (``"[start, stop]"`` for a grid axis); ``empty``
    allows ``lo == hi`` and ``lo > hi`` (a grid axis may run backwards).
    """
    if not isinstance(value, (list, tuple)) or len(value) != 2 or any(isinstance(v, (bool, str)) for v in value):
        raise InvalidParameter(field, f"must be {what}, got {value!r}")
    lo, hi = (check_finite(field, v) for v in value)
    if not empty and lo >= hi:
        raise InvalidParameter(field, f"needs lo < hi, got [{lo:g}, {hi:g}]")
    return lo, hi


_FULL = ("disk full or file-size limit", "free space, then continue with `labrunner resume DIR`")
_OS_HINTS = {  # errno → (what it means here, what to do)
    errno.ENOSPC: _FULL,
    errno.EFBIG: _FULL,
    errno.EDQUOT: _FULL,
    errno.EEXIST: ("a file is where labrunner needs a directory", "move or delete it"),
    errno.ENOTDIR: ("a part of the path is a file, not a directory", "choose another path"),
}


def os_reason(exc: OSError, *, advice: bool = True, command: str = "") -> str:
    """Why an OS call failed, with what it means and (``advice``) what to do where that is clear:
    "No space left on device (disk full …: free space, then …)"; the caller names the path. A
    full disk is continued by ``resume`` after a campaign's ``run`` or ``resume``; any other
    ``command`` (``analyse``: its report) is run again."""
    reason = exc.strerror or str(exc) or type(exc).__name__
    hint = _OS_HINTS.get(exc.errno) if exc.errno is not None else None
    if hint is None:
        return reason
    what, todo = hint
    if hint is _FULL and command and command not in ("run", "resume"):
        todo = f"free space, then run `labrunner {command}` again"
    return f"{reason} ({what}: {todo})" if advice else f"{reason} ({what})"
