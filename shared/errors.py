"""Errors of the mirrorcoach library.

Every error carries a stable ``code`` (the strings the bus uses: ``bad_request``,
``not_found``, ``conflict``, ``unavailable``, ``internal``) so that a service can turn it
into a ``reply_err`` and the CLI into a one-line message, never a traceback.
"""

from __future__ import annotations


class MirrorcoachError(Exception):
    """Base class: a failure the user can act on."""

    code = "internal"

    def __init__(self, message: str, **details):
        super().__init__(message)
        self.message = message
        self.details = details


class BadInput(MirrorcoachError):
    """The caller gave something that cannot be used (shape, value, name)."""

    code = "bad_request"


class NotFound(MirrorcoachError):
    code = "not_found"


class Conflict(MirrorcoachError):
    """The thing is busy with another request, or already exists."""

    code = "conflict"


class Unavailable(MirrorcoachError):
    """Something needed is not running or did not answer in time."""

    code = "unavailable"


class Forbidden(MirrorcoachError):
    """The cluster's access control does not let this identity's role do that."""

    code = "forbidden"


class ClipFormatError(BadInput):
    """A clip or skeleton file cannot be read; names the file and, where known, the line."""

    def __init__(self, path, message: str, line: int | None = None):
        where = f"{path}:{line}" if line is not None else f"{path}"
        super().__init__(f"{where}: {message}", path=str(path), line=line)
        self.path = str(path)
        self.line = line
        self.reason = message


class ModelError(MirrorcoachError):
    """A model could not be trained or used (degenerate HMM, too few frames, ...)."""

    code = "bad_request"


class DamagedFile(BadInput):
    """A file a service saved (an other, a learner, an estimate, a session, a take) cannot be read
    back: a disk's fault, an edit by hand, a file of another program. Names the file, what is
    wrong with it and what to do; the file is kept as it is (:func:`shared.io.saved.read_back`)."""

    def __init__(self, what: str, name: str, path, why: str):
        super().__init__(f"{what} {name!r} cannot be read from its file {path} ({why}); the file is kept as it is: "
                         f"delete the {what} to start it again, or put back a good copy of the file",
                         path=str(path), damaged=what)
        self.what, self.name, self.path, self.why = what, name, str(path), why

    def listed(self) -> dict:
        """Its row in a list verb's ``damaged`` (schemas.common.DAMAGED)."""
        return {"kind": self.what, "name": self.name, "message": self.message}
