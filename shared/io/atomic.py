"""Atomic file writes: a temporary file in the same folder, fsync, then rename, so a crash at
any moment leaves either the old file or the new one (never half of one).

``durable=False`` leaves out the fsync, for state rewritten at every step whose last few steps a
power loss may roll back without harm (a simulated other's question counter, rewritten at every
answer: 21,873 fsyncs in one ``reproduce ch3``, 65 s of waiting in the answers' path, median 1.9
ms and up to 72 ms each while the cluster writes its other files). The rename still makes the
write all or nothing for every crash of the process; only the kernel's own crash or a power loss
can keep the file before it (on ext4, whose ``auto_da_alloc`` flushes a file replaced by rename,
not even that)."""

from __future__ import annotations

import errno
import os
from collections.abc import Callable
from pathlib import Path
from typing import BinaryIO


def atomic_write(path, write: Callable[[BinaryIO], object], durable: bool = True) -> Path:
    """Call ``write(binary_file)`` on a temporary file and move it to ``path`` (synced to the disk
    first unless ``durable`` is False: module docstring)."""
    import tempfile  # here: a command that only reads does not pay its import (1 ms)

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            write(f)
            f.flush()
            if durable:
                os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


#: the errors that say "the disk (or the user's quota) is full", not "this input is bad"
DISK_FULL = (errno.ENOSPC, errno.EDQUOT)


def append_line(path, line: str) -> None:
    """Append ``line`` and a newline to ``path`` all or nothing, and fsync it.

    A write the disk cannot take (``ENOSPC``) may have written part of the line; the file is cut
    back to its length before the call, so a full disk never leaves half a line behind
   . The error is raised after the cut.
    """
    data = (line.rstrip("\n") + "\n").encode()
    fd = os.open(path, os.O_RDWR | os.O_APPEND | os.O_CREAT, 0o600)
    try:
        size = os.fstat(fd).st_size
        if size and os.pread(fd, 1, size - 1) != b"\n":  # a line an older version left torn stays apart
            data = b"\n" + data
        try:
            view = memoryview(data)
            while view:
                view = view[os.write(fd, view):]
            os.fsync(fd)
        except OSError:
            os.ftruncate(fd, size)
            raise
    finally:
        os.close(fd)


def read_lines(path) -> tuple[list[str], int]:
    """The complete lines of a file written by :func:`append_line`, and how many were left out:
    a last line without its newline (a write cut short by a kill) is not a line."""
    text = Path(path).read_text(errors="replace")
    lines = text.split("\n")
    torn = lines.pop()  # "" when the file ends with a newline
    return [x for x in lines if x.strip()], int(bool(torn.strip()))
