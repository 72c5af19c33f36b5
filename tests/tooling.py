"""Tests that drive an outside tool (Chromium, Node.js, arm-none-eabi-gcc, QEMU) call :func:`missing`
where the tool is absent: a skip on a developer's machine, a failure under ``LABRUNNER_CI=1`` (the
README's test command, which installs every tool first), so that CI never passes by skipping them."""

from __future__ import annotations

import os
from typing import NoReturn

import pytest


def missing(why: str) -> NoReturn:
    """Skip (or, under ``LABRUNNER_CI=1``, fail) the calling test because of ``why``."""
    if os.environ.get("LABRUNNER_CI") == "1":
        pytest.fail(f"{why} (LABRUNNER_CI=1: a missing tool fails; tests/setup.sh installs it)")
    pytest.skip(why)
