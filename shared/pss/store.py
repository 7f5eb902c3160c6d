"""Named spaces on disk: the PSS service's state, kept free of the bus.

Every space is one ``<name>.npz`` in the store's folder, written atomically (temporary file,
fsync, rename) by :meth:`ProtoSymbolSpace.save`, so a crash at any moment leaves either the
old file or the new one. A clip added without a rebuild is a **journal entry** beside it,
``<name>.<k>.add`` (:meth:`ProtoSymbolSpace.save_added`: the new proto-symbols, their rows of
distances, their points and the refitted decision, also atomic), so adding to a space of
thousands writes the new rows and the decision (about 0.6 MB, whatever the space's size), not
the whole file; a space is read as its file and its entries in order. An entry names the generation of the file it extends: one left by a rewrite (a crash
between the new file and the removal of the old entries) is skipped. The journal is folded
into the file when it reaches ``JOURNAL_MAX`` entries or a quarter of the space.

A build or add first writes ``<name>.pending.json``; the marker is removed once the new space
is on disk, or at once when the operation fails or is refused (the old file is intact). A
marker found when the store opens belongs to an operation the previous process never finished:
:meth:`interrupted` reports it until the space is built again or deleted. Deployed with a standby
on the same volume, only the instance that leads recovers (when it starts to lead,
:meth:`take_over`): a standby that cleared "half-written" files at its start would delete the
leader's write in progress.

Readers never wait for writers: a space object is never modified in place, a write replaces
it. Two writes to the same space at once are refused (``conflict``); writes to different
spaces run side by side.
"""

from __future__ import annotations

import json
import logging
import os
import re
import threading
import time
from contextlib import contextmanager
from glob import escape as glob_escape
from pathlib import Path

from shared.errors import BadInput, Conflict, NotFound
from shared.io.atomic import atomic_write
from shared.pss.space import ProtoSymbolSpace

log = logging.getLogger("mirrorcoach.pss")


def _operation(marker: Path) -> str:
    try:
        return str(json.loads(marker.read_text()).get("operation", "build"))
    except (OSError, ValueError, AttributeError):
        return "build"


NAME_RE = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}")
JOURNAL_MAX = 32  # entries beside a space's file before the next change rewrites it whole
TAKE_OVER_GRACE_S = 120.0  # SpaceStore.take_over: a temporary file younger than this may be a write in progress


def check_name(name: str) -> str:
    if not isinstance(name, str) or not NAME_RE.fullmatch(name):
        raise BadInput(f"{name!r} is not a valid space name (letters, digits, '_', '.', '-'; no '/' or leading '.')",
                       field="space")
    return name


class SpaceStore:
    """The spaces of one PSS service, in ``root``."""

    def __init__(self, root, recover: bool = True):
        """``recover``: clear what a killed process left (:meth:`recover`) now; a standby on storage
        another instance writes to passes False and recovers when it starts to lead
        (:meth:`take_over`)."""
        self.root = Path(root)
        self.root.mkdir(parents=True, exist_ok=True)
        self._cache: dict[str, ProtoSymbolSpace] = {}
        self._busy: set[str] = set()
        self._lock = threading.Lock()
        if recover:
            self.recover()

    def recover(self, older_than_s: float = 0.0) -> None:
        """Remove the temporary files a killed process left half-written (those not written to for
        ``older_than_s``) and settle the markers of operations it never finished (module
        docstring). Only the instance that writes may call it: on a shared volume another
        instance's write in progress is a temporary file too."""
        now = time.time()
        for pattern in (".*.npz.*", ".*.add.*"):
            for tmp in self.root.glob(pattern):
                try:
                    if now - tmp.stat().st_mtime >= older_than_s:
                        tmp.unlink(missing_ok=True)
                except FileNotFoundError:  # renamed by its writer meanwhile
                    pass
        for m in self.root.glob("*.pending.json"):
            name = m.name[: -len(".pending.json")]
            try:
                empty = m.stat().st_size == 0
            except FileNotFoundError:  # its operation ended meanwhile (a stepped-down leader's)
                continue
            if empty:  # a marker an older version could not finish writing (a full disk):
                m.unlink(missing_ok=True)  # written before any work, so no operation began
            elif NAME_RE.fullmatch(name) and self.path(name).exists():
                # a replace or an add the previous process never finished: the space is as it was
                # before it (its file and journal are written atomically), so nothing is left to
                # report beyond this line; its client was told when the process died
                log.warning("space %r: a %s started before the service last stopped never finished; the space is "
                            "as it was before it", name, _operation(m))
                m.unlink(missing_ok=True)

    def take_over(self) -> None:
        """A standby starts to lead (shared/bus/runtime.py): drop the spaces kept in memory (another
        instance may have changed the files) and recover, leaving the temporary files written
        in the last ``TAKE_OVER_GRACE_S``: a leader that lost its router steps down, but a write it
        had begun may still be finishing."""
        self.forget()
        self.recover(older_than_s=TAKE_OVER_GRACE_S)

    def forget(self) -> None:
        """Drop the spaces kept in memory: the files are the truth (a standby that starts to lead,
        shared/bus/runtime.py)."""
        with self._lock:
            self._cache.clear()

    # ------------------------------------------------------------------ paths
    def path(self, name: str) -> Path:
        return self.root / f"{check_name(name)}.npz"

    def journal(self, name: str) -> list[Path]:
        """The space's journal entries, in the order written."""
        check_name(name)
        entries = []
        for p in self.root.glob(f"{glob_escape(name)}.*.add"):
            k = p.name[len(name) + 1:-len(".add")]
            if k.isdigit():
                entries.append((int(k), p))
        return [p for _, p in sorted(entries)]

    def _marker(self, name: str) -> Path:
        return self.root / f"{check_name(name)}.pending.json"

    # ------------------------------------------------------------------ reading
    def names(self) -> list[str]:
        return sorted(p.stem for p in self.root.glob("*.npz") if NAME_RE.fullmatch(p.stem))

    def exists(self, name: str) -> bool:
        return self.path(name).exists()

    def get(self, name: str) -> ProtoSymbolSpace:
        with self._lock:
            sp = self._cache.get(name)
        if sp is not None:
            return sp
        p = self.path(name)
        if not p.exists():
            raise NotFound(f"no space named {name!r} (spaces: {', '.join(self.names()) or 'none'})", space=name)
        sp = ProtoSymbolSpace.load(p, added=self.journal(name))
        sp.name = name
        with self._lock:
            return self._cache.setdefault(name, sp)

    def interrupted(self) -> list[dict]:
        out = []
        for m in sorted(self.root.glob("*.pending.json")):
            name = m.name[: -len(".pending.json")]
            with self._lock:
                if name in self._busy:
                    continue
            try:  # a marker may vanish meanwhile: its operation finished, nothing was interrupted
                info = json.loads(m.read_text())
                started = float(info.get("started", m.stat().st_mtime))
            except FileNotFoundError:
                continue
            except (OSError, ValueError, TypeError, AttributeError):
                info, started = {}, None
            if started is None:
                try:
                    started = m.stat().st_mtime
                except FileNotFoundError:
                    continue
            out.append({"space": name, "operation": str(info.get("operation", "build")), "started": started})
        return out

    # ------------------------------------------------------------------ writing
    @contextmanager
    def writing(self, name: str, operation: str):
        """Hold the write slot of ``name`` with an on-disk marker; refuse a second writer."""
        check_name(name)
        with self._lock:
            if name in self._busy:
                raise Conflict(f"space {name!r} is being changed by another request; try again when it is done", space=name)
            self._busy.add(name)
        marker = self._marker(name)
        try:
            record = json.dumps({"operation": operation, "started": time.time(), "pid": os.getpid()}).encode()
            atomic_write(marker, lambda f: f.write(record))  # never an empty marker, even on a full disk
            try:
                yield
            except BaseException:  # refused or failed (a full disk): the old space is intact, nothing to report
                marker.unlink(missing_ok=True)
                raise
        finally:
            with self._lock:
                self._busy.discard(name)

    def commit(self, name: str, space: ProtoSymbolSpace) -> None:
        """Write the space atomically, then publish it to readers and drop the marker (and the
        journal, which the new file holds: its entries name the old file's generation)."""
        space.name = name
        space.save(self.path(name))
        for entry in self.journal(name):
            entry.unlink(missing_ok=True)
        with self._lock:
            self._cache[name] = space
        self._marker(name).unlink(missing_ok=True)

    def append(self, name: str, space: ProtoSymbolSpace, first: int) -> None:
        """Keep ``space``, made by :meth:`ProtoSymbolSpace.added` from the stored space of
        ``first`` proto-symbols, as a journal entry; the whole file instead when the journal is
        long (``JOURNAL_MAX`` entries or a quarter of the proto-symbols in it)."""
        entries = self.journal(name)
        in_journal = len(space.symbols) - space.base_count
        if space.generation is None or len(entries) >= JOURNAL_MAX or in_journal > max(len(space.symbols) // 4, 1):
            self.commit(name, space)
            return
        space.name = name
        k = int(entries[-1].name[len(name) + 1:-len(".add")]) + 1 if entries else 1
        space.save_added(self.root / f"{name}.{k:04d}.add", first)
        with self._lock:
            self._cache[name] = space
        self._marker(name).unlink(missing_ok=True)

    def delete(self, name: str) -> bool:
        with self._lock:
            if name in self._busy:
                raise Conflict(f"space {name!r} is being changed; delete it when that is done", space=name)
            self._cache.pop(name, None)
        existed = self.path(name).exists()
        marker = self._marker(name)
        if not existed and not marker.exists():
            raise NotFound(f"no space named {name!r}", space=name)
        self.path(name).unlink(missing_ok=True)
        for entry in self.journal(name):
            entry.unlink(missing_ok=True)
        marker.unlink(missing_ok=True)
        return existed
