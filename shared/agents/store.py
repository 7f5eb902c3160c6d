"""The simulator's agents on disk (bus-free): others as JSON, learners as NPZ, atomic writes.

``others/<name>.json``: ``{"kind": "simulated"|"person", ...}``; a person's seat keeps only
its density ``d``. ``learners/<name>.npz``: the target clip, the parameters, the motor memory,
the reference and the trial count, so a restarted simulator continues every learner where it was.

A file that cannot be read back (:mod:`shared.io.saved`) does not stop the store: its agent is
:attr:`AgentStore.damaged`, listed as such, answered with what is wrong with its file (kept as
it is), and deleted or created again with ``replace`` only when asked.
"""

from __future__ import annotations

import json
import logging
import re
import threading
from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from shared.agents.learner import LearnerParams, SimulatedLearner
from shared.agents.other import OtherParams, SimulatedOther
from shared.errors import BadInput, Conflict, DamagedFile, NotFound
from shared.estimation.symbols import WORDS
from shared.io.atomic import atomic_write
from shared.io.saved import read_back
from shared.motion.clip import Clip
from shared.motion.skeleton import Skeleton

NAME_RE = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}")
log = logging.getLogger("mirrorcoach.agents")
T = TypeVar("T")


class PersonOther:
    """A person in the other's seat: answers come from the CLI (``mirrorcoach other answer``)."""

    def __init__(self, name: str, d: int = 4):
        if d not in WORDS:
            raise BadInput(f"density d must be one of {sorted(WORDS)}, got {d}", field="d")
        self.name, self.d, self.asked = name, d, 0

    def to_dict(self) -> dict:
        return {"name": self.name, "asked": self.asked, "params": {"d": self.d}}

    def reveal(self) -> dict:
        return {"name": self.name, "asked": self.asked, "d": self.d}


def _check(name: str) -> str:
    if not NAME_RE.fullmatch(name or ""):
        raise BadInput(f"{name!r} is not a valid name (letters, digits, '_', '.', '-')")
    return name


class AgentStore:
    def __init__(self, root):
        self.root = Path(root)
        (self.root / "others").mkdir(parents=True, exist_ok=True)
        (self.root / "learners").mkdir(parents=True, exist_ok=True)
        self.lock = threading.RLock()
        self.reload()

    def reload(self) -> None:
        """Read every other and learner from the files (at start, and when a standby starts to lead:
        another instance may have changed them, shared/bus/runtime.py)."""
        damaged: dict[tuple[str, str], DamagedFile] = {}
        others = self._read_all("other", "json", self._load_other, damaged)
        learners = self._read_all("learner", "npz", self._load_learner, damaged)
        with self.lock:
            self.others, self.learners, self.damaged = others, learners, damaged

    def _read_all(self, kind: str, ext: str, load: Callable[[Path], T], damaged: dict) -> dict[str, T]:
        """Every ``kind``'s file read with ``load``; a damaged one goes into ``damaged`` (logged), not in the result."""
        out = {}
        for p in sorted((self.root / f"{kind}s").glob(f"*.{ext}")):
            try:
                out[p.stem] = load(p)
            except DamagedFile as e:
                log.warning("%s", e.message)
                damaged[kind, p.stem] = e
            except NotFound:  # deleted while listed
                continue
        return out

    def _refuse_damaged(self, kind: str, name: str) -> None:
        """Raise what is wrong with the file of the ``kind`` (other or learner) ``name``, if it is damaged."""
        e = self.damaged.get((kind, name))
        if e is not None:  # a new error each time (one raised again and again would keep every traceback)
            raise DamagedFile(e.what, e.name, e.path, e.why)

    def _refuse_existing(self, kind: str, name: str, table: dict, replace: bool) -> None:
        if replace:
            return
        if name in table:
            raise Conflict(f"{kind} {name!r} exists; delete it or create with replace", **{kind: name})
        if (kind, name) in self.damaged:
            raise Conflict(f"{kind} {name!r} exists but its file cannot be read ({self.damaged[kind, name].why}); "
                           f"delete it or create with replace (its file is then overwritten)", **{kind: name})

    @staticmethod
    def _load_other(path: Path) -> tuple[str, SimulatedOther | PersonOther]:
        with read_back(path, "other", path.stem):
            d = json.loads(path.read_text())
            kind = d.get("kind", "simulated")
            if kind not in ("simulated", "person"):
                raise ValueError(f"kind {kind!r} is neither 'simulated' nor 'person'")
            obj = SimulatedOther.from_dict(d) if kind == "simulated" else PersonOther(d["name"], int(d["params"]["d"]))
            obj.asked = int(d.get("asked", 0))
            return kind, obj

    def _saving(self, table: dict, name: str, path: Path, load, write, durable: bool = True) -> None:
        """Write ``table[name]`` to ``path``; when the write fails (a full disk), put back what is on
        disk, so memory never runs ahead of the files (an other's noise, a learner's memory)."""
        try:
            atomic_write(path, write, durable)
        except OSError:
            with self.lock:
                try:
                    table[name] = load(path)
                except (NotFound, DamagedFile):  # nothing, or nothing readable, on disk: not in memory either
                    table.pop(name, None)
            raise

    # ------------------------------------------------------------------ others
    def add_other(self, name: str, kind: str, params: dict, replace: bool = False):
        _check(name)
        with self.lock:
            self._refuse_existing("other", name, self.others, replace)
            obj: SimulatedOther | PersonOther
            if kind == "person":
                obj = PersonOther(name, int(params.get("d", 4)))
            else:
                obj = SimulatedOther(name, OtherParams(**{k: v for k, v in params.items() if v is not None}))
            self.others[name] = (kind, obj)
            self.save_other(name)
            self.damaged.pop(("other", name), None)
        return kind, obj

    def other(self, name: str):
        with self.lock:
            self._refuse_damaged("other", name)
            if name not in self.others:
                raise NotFound(f"no other named {name!r} (others: {', '.join(sorted(self.others)) or 'none'})", other=name)
            return self.others[name]

    def save_other(self, name: str, durable: bool = True) -> None:
        """Write the other's file; ``durable=False`` after an answer, when only its question counter
        moved: atomic, not synced (:mod:`shared.io.atomic`; a power loss may replay the last answers'
        random draws, never lose the other)."""
        kind, obj = self.others[name]
        text = json.dumps({"kind": kind, **obj.to_dict()}).encode()
        self._saving(self.others, name, self.root / "others" / f"{_check(name)}.json", self._load_other,
                     lambda f: f.write(text), durable)

    # ------------------------------------------------------------------ learners
    def add_learner(self, name: str, learner: SimulatedLearner, replace: bool = False) -> None:
        _check(name)
        with self.lock:
            self._refuse_existing("learner", name, self.learners, replace)
            self.learners[name] = learner
            self.save_learner(name)
            self.damaged.pop(("learner", name), None)

    def learner(self, name: str) -> SimulatedLearner:
        with self.lock:
            self._refuse_damaged("learner", name)
            if name not in self.learners:
                raise NotFound(f"no learner named {name!r} (learners: {', '.join(sorted(self.learners)) or 'none'})",
                               learner=name)
            return self.learners[name]

    def save_learner(self, name: str) -> None:
        lr = self.learners[name]
        t = lr.target
        header = {"name": lr.name, "trials": lr.trials, "params": asdict(lr.params), "channels": t.channels,
                  "fps": t.fps, "groups": t.groups, "label": t.label, "target_name": t.name,
                  "skeleton": None if t.skeleton is None else t.skeleton.to_json()}
        arrays: dict[str, Any] = {"target": t.data, "memory": lr.memory, "header": np.array(json.dumps(header))}
        if lr.reference is not None:
            arrays["reference"] = lr.reference
        if np.any(lr.fast):
            arrays["fast"] = lr.fast
        self._saving(self.learners, name, self.root / "learners" / f"{_check(name)}.npz", self._load_learner,
                     lambda f: np.savez(f, **arrays))

    @staticmethod
    def _load_learner(path: Path) -> SimulatedLearner:
        with read_back(path, "learner", path.stem, npz=True), np.load(path, allow_pickle=False) as z:
            h = json.loads(str(z["header"]))
            sk = Skeleton.from_json(h["skeleton"]) if h["skeleton"] else None
            target = Clip(z["target"], h["channels"], h["fps"], sk, h["groups"], name=h["target_name"], label=h["label"])
            ref = z["reference"] if "reference" in z.files else None
            fast = z["fast"] if "fast" in z.files else None
            return SimulatedLearner(h["name"], target, LearnerParams(**h["params"]), memory=z["memory"],
                                    trials=int(h["trials"]), reference=ref, fast=fast)

    # ------------------------------------------------------------------ both
    def delete(self, other: str | None = None, learner: str | None = None) -> str:
        if (other is None) == (learner is None):
            raise BadInput("delete: give exactly one of other and learner")
        kind, name = ("other", other) if other is not None else ("learner", learner)
        assert name is not None  # (exactly one of the two, checked above)
        table = self.others if kind == "other" else self.learners
        with self.lock:
            if self.damaged.pop((kind, name), None) is None:  # a damaged one's file goes when asked to
                (self.other if kind == "other" else self.learner)(name)  # NotFound when there is none
                del table[name]
            (self.root / f"{kind}s" / f"{_check(name)}.{'json' if kind == 'other' else 'npz'}").unlink(missing_ok=True)
            return name
