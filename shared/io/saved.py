"""Reading back what a service saved (its others, learners, estimates, sessions and takes).

A saved file may be damaged in ways no write of ours leaves (every write is atomic,
:mod:`shared.io.atomic`): a disk's fault, an edit by hand, a file another program or version put
there. Reading it must not end in a traceback, nor in a service that cannot start because one of
its files cannot be read (one damaged learner kept the simulator restarting for ever, and with it
every simulation of the cluster). :func:`read_back` turns whatever reading the file raises into a
:class:`~shared.errors.DamagedFile` that names the file, what is wrong with it and what to do; the
file itself is never changed, so nothing is lost that a good copy could put back.
"""

from __future__ import annotations

import zipfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from shared.errors import BadInput, DamagedFile, NotFound
from shared.io.npz import npz_problem

#: what a saved NPZ file (a learner, an estimate) may unpack to, checked before numpy reads it:
#: far above any the services write (an estimate of 100 motions is a few MB)
MAX_SAVED_BYTES = 2 * 1024 ** 3

#: what reading a damaged file raises: the file's bytes or the JSON and arrays in it are not what
#: the reader expects (a value out of range is refused by the objects built from it: BadInput; JSON
#: nested deeper than the parser recurses: RecursionError; a count of 1e999: OverflowError)
DAMAGE = (BadInput, OSError, ValueError, KeyError, TypeError, IndexError, AttributeError, EOFError,
          RecursionError, OverflowError, zipfile.BadZipFile)


@contextmanager
def read_back(path, what: str, name: str, npz: bool = False) -> Iterator[Path]:
    """Read the saved ``what`` called ``name`` from ``path`` inside the ``with``: anything
    :data:`DAMAGE` holds becomes :class:`DamagedFile`, a file gone since it was listed
    :class:`NotFound`. With ``npz``, the archive is first checked as a space file is
    (:func:`shared.io.npz.npz_problem`): numpy never allocates what a damaged header declares,
    nor unpickles anything."""
    path = Path(path)
    if npz and path.is_file():
        why = npz_problem(path, {}, MAX_SAVED_BYTES)
        if why is not None:
            raise DamagedFile(what, name, path, why)
    try:
        yield path
    except FileNotFoundError:
        raise NotFound(f"no {what} {name!r}") from None
    except DamagedFile:
        raise
    except DAMAGE as e:
        raise DamagedFile(what, name, path, f"{type(e).__name__}: {e}") from None
