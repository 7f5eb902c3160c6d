"""Compiled kernels (numba), each optionally with a numpy twin for one-shot commands.

A process pays numba once before its first kernel runs: the import (about 0.2 s here) and
loading the cached machine code with its target context (about 0.5 s), while recognising one
clip is about 10 ms of array work. Long-lived processes (the services, builds, benchmarks)
amortise that; a command that starts, recognises one clip and exits does not
(``mirrorcoach offline recognize``). :func:`kernel` compiles a function with ``numba.njit`` on
its first call, *unless* numba is off for the process (:func:`use_numba` ``(False)``, or
``MIRRORCOACH_NUMBA=0`` in the environment) and the kernel has a numpy twin
(:meth:`Kernel.numpy`), which then runs instead. Every twin is tested against its kernel
(``tests/test_pss_math.py``). A kernel without a twin always compiles.

Kernels may call other kernels: compiling one compiles the kernels it names first and puts
their numba dispatchers in the module's globals, where numba looks them up.
"""

from __future__ import annotations

import os

_NUMBA: bool | None = None  # None: the environment decides


def use_numba(on: bool | None) -> None:
    """Run the kernels compiled (``True``), through their numpy twins where they have one
    (``False``), or as ``MIRRORCOACH_NUMBA`` says (``None``, the default: on)."""
    global _NUMBA
    _NUMBA = on


def numba_on() -> bool:
    if _NUMBA is not None:
        return _NUMBA
    return os.environ.get("MIRRORCOACH_NUMBA", "1").strip().lower() not in ("0", "false", "no", "off")


class Kernel:
    """A function compiled by ``numba.njit(**options)`` on first use (see the module docstring)."""

    def __init__(self, fn, options: dict):
        self.py = fn
        self.options = options
        self.twin = None
        self._compiled = None
        self.__doc__, self.__name__, self.__wrapped__ = fn.__doc__, fn.__name__, fn

    def numpy(self, twin):
        """Register ``twin`` (same arguments, same results) as this kernel's numpy path."""
        self.twin = twin
        return twin

    def compiled(self):
        """The numba dispatcher (compiled, or loaded from numba's cache, on first use)."""
        if self._compiled is None:
            import numba

            names = self.py.__globals__
            for name in self.py.__code__.co_names:
                helper = names.get(name)
                if isinstance(helper, Kernel):
                    names[name] = helper.compiled()
            self._compiled = numba.njit(**self.options)(self.py)
        return self._compiled

    def __call__(self, *args):
        if self._compiled is None and self.twin is not None and not numba_on():
            return self.twin(*args)
        return self.compiled()(*args)


def kernel(**options):
    """Decorator: ``@kernel(cache=True, nogil=True)`` is ``@numba.njit(...)`` compiled on first call."""
    def wrap(fn) -> Kernel:
        return Kernel(fn, options)
    return wrap
