"""Run one piece of the analysis in a forked child while the process goes on with the rest.

``analyse`` draws its figures in a child forked *ahead*, before it imports pandas
(:meth:`Background.ahead`): the child loads matplotlib on the other core meanwhile, then draws
the run plots and maps the table names, sent to it pickled as plain data; it forks a child of
its own (a plain :class:`Background`) for part of the maps, which pays no imports and starts at
once (:mod:`.drawing`). A result comes back pickled through
a pipe. Where there is no ``fork`` (Windows) or when the child fails, the function simply runs in
this process when its result is asked for: the same result, only later.
"""

from __future__ import annotations

import contextlib
import gc
import os
import pickle
import signal
import sys
import warnings
from collections.abc import Callable
from typing import Any, Generic, TypeVar

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

    def __init__(self, fn: Callable[[], T] | None) -> None:
        self._fn = fn
        self._pid = 0
        self._read = -1
        self._send = -1  # an ahead child's task pipe, until :meth:`start`
        if fn is not None and hasattr(os, "fork"):
            self._fork(lambda: fn)

    @classmethod
    def ahead(cls, prepare: Callable[[], object]) -> Background[Any]:
        """A child forked now, before its function exists: it runs ``prepare()`` (imports,
        on another core) and then waits for the function :meth:`start` sends it."""
        job: Background[Any] = cls(None)
        if hasattr(os, "fork"):
            task, job._send = os.pipe()

            def receive() -> Callable[[], Any]:
                os.close(job._send)
                prepare()
                with os.fdopen(task, "rb") as pipe:
                    return pickle.load(pipe)  # EOFError (exit 1) when closed without a task

            job._fork(receive)
            os.close(task)
            if not job._pid:  # no fork: the function will run here
                os.close(job._send)
                job._send = -1
        return job

    def start(self, fn: Callable[[], T]) -> None:
        """Hand an :meth:`ahead` child its function: a small one that pickles by name (a
        module-level function or a ``functools.partial`` of one)."""
        self._fn = fn
        if self._send >= 0:
            with contextlib.suppress(BrokenPipeError), os.fdopen(self._send, "wb") as pipe:
                # protocol 5 writes the maps' arrays from their memory, without a copy of each first
                pickle.dump(fn, pipe, protocol=5)  # a child that died already: result() runs fn here
            self._send = -1

    def _fork(self, task: Callable[[], Callable[[], T]]) -> None:
        """Fork a child that runs the function ``task()`` returns and pickles its result to a pipe."""
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
                fn = task()
                with os.fdopen(write, "wb") as pipe:
                    pickle.dump(fn(), pipe)
                code = 0
            finally:
                os._exit(code)
        os.close(write)
        self._pid, self._read = pid, read

    def result(self) -> T:
        """The child's result; if there is no child or it failed, ``fn()`` run here. Asked once:
        the function, and what it holds (the maps' cells), is let go."""
        fn, self._fn = self._fn, None
        assert fn is not None, "start() an ahead child before asking for its result"
        if not self._pid:
            return fn()
        with os.fdopen(self._read, "rb") as pipe:
            data = pipe.read()
        _, status = os.waitpid(self._pid, 0)
        self._pid = 0
        _unfreeze()
        if status == 0 and data:
            return pickle.loads(data)
        return fn()

    def close(self) -> None:
        """Wait for a child whose result is no longer wanted (the analysis failed before it); an
        ahead child that was given nothing to do is stopped at once (it only imports)."""
        if self._send >= 0:
            os.close(self._send)
            self._send = -1
            if self._pid:
                with contextlib.suppress(ProcessLookupError):
                    os.kill(self._pid, signal.SIGKILL)
        if self._pid:
            os.close(self._read)
            os.waitpid(self._pid, 0)
            self._pid = 0
            _unfreeze()
