"""Run one piece of the analysis in a forked child while the process goes on with the rest.

``analyse`` draws the run plots (reading their logs, ~0.17 s a plot) in a child forked once the
table is built, and the second half of the maps in one forked once their overlays are computed:
the children pay no imports and start at once, while this process writes the tables and draws the
other maps; on two cores that takes most of the drawing off the analysis's wall time. A result
comes back pickled through a pipe. Where there is no ``fork`` (Windows) or when the child fails,
the function simply runs in this process when its result is asked for: the same result, only
later.
"""

from __future__ import annotations

import gc
import os
import pickle
import sys
import warnings
from collections.abc import Callable
from typing import Generic, TypeVar

T = TypeVar("T")
_children = 0  # children running: the collector stays frozen until the last one is collected


def _freeze() -> None:
    global _children
    gc.freeze()  # neither process's collector walks (and so copies) the objects they share
    _children += 1


def _unfreeze() -> None:
    global _children
    _children -= 1
    if not _children:
        gc.unfreeze()


class Background(Generic[T]):
    """``fn()`` in a forked child (if ``fork``); :meth:`result` waits for it and returns its value."""

    def __init__(self, fn: Callable[[], T]) -> None:
        self._fn = fn
        self._pid = 0
        self._read = -1
        if hasattr(os, "fork"):
            self._start()

    def _start(self) -> None:
        read, write = os.pipe()
        for stream in (sys.stdout, sys.stderr):  # nothing buffered twice
            stream.flush()
        _freeze()
        with warnings.catch_warnings():  # 3.12+ warns on fork with threads; the child only draws and writes files
            warnings.simplefilter("ignore", DeprecationWarning)
            try:
                pid = os.fork()
            except OSError:  # no process to spare: run in this process when the result is asked for
                _unfreeze()
                os.close(read)
                os.close(write)
                return
        if pid == 0:  # the child: never returns into the caller's code
            code = 1
            try:
                gc.disable()
                os.close(read)
                with os.fdopen(write, "wb") as pipe:
                    pickle.dump(self._fn(), pipe)
                code = 0
            finally:
                os._exit(code)
        os.close(write)
        self._pid, self._read = pid, read

    def result(self) -> T:
        """The child's result; if there is no child or it failed, ``fn()`` run here."""
        if not self._pid:
            return self._fn()
        with os.fdopen(self._read, "rb") as pipe:
            data = pipe.read()
        _, status = os.waitpid(self._pid, 0)
        self._pid = 0
        _unfreeze()
        if status == 0 and data:
            return pickle.loads(data)
        return self._fn()

    def close(self) -> None:
        """Wait for a child whose result is no longer wanted (the analysis failed before it)."""
        if self._pid:
            os.close(self._read)
            os.waitpid(self._pid, 0)
            self._pid = 0
            _unfreeze()
