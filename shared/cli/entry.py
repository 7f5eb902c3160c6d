"""The ``mirrorcoach`` command's entry point: the command line of :mod:`shared.cli.app`, its
imports made without the cyclic garbage collector (:func:`shared.cli.lasting_imports`) and
its exit without a last collection of them.

A command's objects are collected as usual while it runs. At exit, what is still alive is
frozen, so the interpreter's final collection does not walk every object the imports made
(~20 ms of a one-clip command, measured by ``python -m bench.bus``): the process ends and the
system takes its memory back. Files are written through ``with`` blocks and closed when they
end, never by the collector. A program that uses the command line as a library imports
:mod:`shared.cli.app`, which leaves the collector alone."""

import gc

from shared.cli import lasting_imports

with lasting_imports():
    from shared.cli.app import main as _app_main


def main() -> None:
    try:
        _app_main()
    finally:
        gc.freeze()


if __name__ == "__main__":
    main()
