"""Declarative message contracts, validated at the service boundary.

A small vocabulary (``Str``, ``Int``, ``Float``, ``Bool``, ``Array``, ``List``, ``Map``,
``MapOf``) says what each field may hold; ``Message`` adds a name, a version and a
description. ``validate`` returns the checked message (defaults filled in) or raises
:class:`shared.errors.BadInput` naming the field, e.g. ``clip.data: contains NaN or Inf``.
``describe`` renders a contract for a person (``mirrorcoach schemas``).

Why our own: the messages carry numpy arrays whose dtype, shape and finiteness are the point
of the check, which general schema libraries leave to custom hooks; this stays ~200 lines and
is the single declaration services and contract tests import.
"""

from __future__ import annotations

import math
import re
from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cache
from typing import Any

import numpy as np

from shared.bus.codec import DEFAULT_MAX_PAYLOAD
from shared.errors import BadInput

NAME_PATTERN = r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}"  # no '/', no leading '.', so never a path


class Spec(ABC):
    """What a field may hold: ``check`` returns the value (converted where allowed) or raises
    :class:`BadInput` naming ``path``; ``describe`` says it for a person."""

    doc: str = ""

    @abstractmethod
    def check(self, value, path: str): ...

    @abstractmethod
    def describe(self) -> str: ...


@cache
def _compiled(pattern: str) -> re.Pattern:
    """A field's pattern compiled once (``re``'s own cache is a lookup and a lock per call)."""
    return re.compile(pattern)


def _fail(path: str, problem: str, **details):
    raise BadInput(f"{path}: {problem}" if path else problem, field=path, **details)


@dataclass
class Str(Spec):
    pattern: str | None = None
    max_len: int = 256
    choices: tuple[str, ...] | None = None
    doc: str = ""

    def check(self, value, path):
        if not isinstance(value, str):
            _fail(path, f"must be a string, got {type(value).__name__}")
        if len(value) > self.max_len:
            _fail(path, f"is longer than {self.max_len} characters")
        if self.choices is not None and value not in self.choices:
            _fail(path, f"must be one of {', '.join(self.choices)}; got {value!r}")
        if self.pattern is not None and not _compiled(self.pattern).fullmatch(value):
            _fail(path, f"{value!r} is not a valid name (letters, digits, '_', '.', '-'; no '/' or leading '.')")
        return value

    def describe(self):
        if self.choices:
            return "one of " + " | ".join(self.choices)
        return f"string matching {self.pattern}" if self.pattern else f"string (<= {self.max_len} chars)"


@dataclass
class Bytes(Spec):
    max_len: int = DEFAULT_MAX_PAYLOAD
    doc: str = ""

    def check(self, value, path):
        if not isinstance(value, (bytes, bytearray)):
            _fail(path, f"must be bytes, got {type(value).__name__}")
        if len(value) > self.max_len:
            _fail(path, f"is longer than {self.max_len} bytes")
        return bytes(value)

    def describe(self):
        return f"bytes (<= {self.max_len})"


@dataclass
class Int(Spec):
    min: int | None = None
    max: int | None = None
    doc: str = ""

    def check(self, value, path):
        if isinstance(value, bool) or not isinstance(value, int):
            _fail(path, f"must be an integer, got {type(value).__name__}")
        return _in_range(value, self.min, self.max, path)

    def describe(self):
        return "int" + _range(self.min, self.max)


@dataclass
class Float(Spec):
    min: float | None = None
    max: float | None = None
    doc: str = ""

    def check(self, value, path):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            _fail(path, f"must be a number, got {type(value).__name__}")
        try:
            value = float(value)
        except OverflowError:  # an integer beyond a float's range
            _fail(path, "must be finite (no NaN or Inf)")
        if not math.isfinite(value):
            _fail(path, "must be finite (no NaN or Inf)")
        return _in_range(value, self.min, self.max, path)

    def describe(self):
        return "float" + _range(self.min, self.max)


@dataclass
class Bool(Spec):
    doc: str = ""

    def check(self, value, path):
        if not isinstance(value, bool):
            _fail(path, f"must be true or false, got {type(value).__name__}")
        return value

    def describe(self):
        return "bool"


@dataclass
class Array(Spec):
    """A numpy array; ``shape`` entries are ``None`` (any) or a fixed size; ``min_shape``
    gives lower bounds. Integer arrays are accepted where floats are asked and converted."""

    shape: tuple[int | None, ...] = (None,)
    kind: str = "f"  # numpy dtype kinds accepted: f float, i int, b bool
    min_shape: tuple[int, ...] | None = None
    max_elements: int = 50_000_000
    finite: bool = True
    doc: str = ""

    def check(self, value, path):
        if not isinstance(value, np.ndarray):
            _fail(path, f"must be an array ({self.describe()}), got {type(value).__name__}")
        if value.ndim != len(self.shape):
            _fail(path, f"must have {len(self.shape)} dimension(s), got shape {list(value.shape)}")
        for i, (n, want) in enumerate(zip(value.shape, self.shape)):
            if want is not None and n != want:
                _fail(path, f"dimension {i} must be {want}, got shape {list(value.shape)}")
        if self.min_shape is not None:
            for i, (n, lo) in enumerate(zip(value.shape, self.min_shape)):
                if n < lo:
                    _fail(path, f"dimension {i} must be at least {lo}, got shape {list(value.shape)}")
        if value.size > self.max_elements:
            _fail(path, f"has {value.size} elements, more than {self.max_elements}")
        accepted = self.kind + ("iu" if "f" in self.kind else "")
        if value.dtype.kind not in accepted:
            _fail(path, f"must have dtype kind {self.kind!r}, got {value.dtype}")
        if "f" in self.kind and value.dtype.kind in "iu":
            value = value.astype(np.float64)
        if self.finite and value.dtype.kind == "f" and not np.all(np.isfinite(value)):
            _fail(path, "contains NaN or Inf")
        return value

    def describe(self):
        dims = " x ".join("*" if n is None else str(n) for n in self.shape)
        kinds = {"f": "float", "i": "int", "b": "bool"}
        lo = f", at least {list(self.min_shape)}" if self.min_shape else ""
        return f"array[{dims}] of {'/'.join(kinds.get(k, k) for k in self.kind)}{lo}" + (", finite" if self.finite else "")


@dataclass
class List(Spec):
    item: Spec
    min_len: int = 0
    max_len: int = 10_000
    doc: str = ""

    def check(self, value, path):
        if not isinstance(value, (list, tuple)):
            _fail(path, f"must be a list, got {type(value).__name__}")
        if not self.min_len <= len(value) <= self.max_len:
            _fail(path, f"must have {self.min_len} to {self.max_len} items, got {len(value)}")
        return [self.item.check(v, f"{path}[{i}]") for i, v in enumerate(value)]

    def describe(self):
        return f"list of {self.item.describe()} ({self.min_len}..{self.max_len} items)"


@dataclass
class MapOf(Spec):
    """A map with free keys (checked by ``key``) and values checked by ``value``."""

    key: Spec
    value: Spec
    min_len: int = 0
    max_len: int = 1000
    doc: str = ""

    def check(self, value, path):
        if not isinstance(value, dict):
            _fail(path, f"must be a map, got {type(value).__name__}")
        if not self.min_len <= len(value) <= self.max_len:
            _fail(path, f"must have {self.min_len} to {self.max_len} entries, got {len(value)}")
        return {self.key.check(k, f"{path}.<key>"): self.value.check(v, f"{path}.{k}") for k, v in value.items()}

    def describe(self):
        return f"map {self.key.describe()} -> {self.value.describe()}"


@dataclass
class AnyMap(Spec):
    """A map whose content is not constrained (error details, free metadata)."""

    max_len: int = 100
    doc: str = ""

    def check(self, value, path):
        if not isinstance(value, dict):
            _fail(path, f"must be a map, got {type(value).__name__}")
        if len(value) > self.max_len:
            _fail(path, f"must have at most {self.max_len} entries")
        return value

    def describe(self):
        return "map (free-form)"


@dataclass
class F:
    """A field of a map: its spec, whether it is required, its default and what it means."""

    spec: Spec
    doc: str = ""
    required: bool = True
    default: Any = None


@dataclass
class Map(Spec):
    fields: dict[str, F]
    checks: list[Callable[[dict, str], None]] = field(default_factory=list)
    doc: str = ""

    def check(self, value, path):
        if not isinstance(value, dict):
            _fail(path, f"must be a map, got {type(value).__name__}")
        names = self.__dict__.get("_names")
        if names is None:  # the fields' names as a set, made once (a message is checked on every request)
            names = self.__dict__["_names"] = frozenset(self.fields)
        if not value.keys() <= names:  # a key that names no field: which, and why
            odd = [k for k in value if not isinstance(k, str)]
            if odd:  # msgpack keeps bytes keys as bytes: a map of field names has text keys only
                _fail(path, f"field names must be text, got {type(odd[0]).__name__} {odd[0]!r:.40}")
            unknown = sorted(set(value) - names)
            _fail(path, f"unknown field(s) {', '.join(map(str, unknown))}; expected {', '.join(self.fields)}")
        out = {}
        for name, f in self.fields.items():
            sub = f"{path}.{name}" if path else name
            if name not in value or value[name] is None:
                if f.required:
                    _fail(sub, "is missing")
                out[name] = f.default() if callable(f.default) else f.default
            else:
                out[name] = f.spec.check(value[name], sub)
        for c in self.checks:
            c(out, path)
        return out

    def describe(self, indent: int = 2) -> str:
        pad = " " * indent
        lines = []
        for name, f in self.fields.items():
            opt = "" if f.required else f" (optional, default {f.default!r})" if not callable(f.default) else " (optional)"
            head = f"{pad}{name}: "
            if isinstance(f.spec, Map):
                lines.append(f"{head}map{opt}" + (f"  # {f.doc}" if f.doc else ""))
                lines.append(f.spec.describe(indent + 4))
            elif isinstance(f.spec, List) and isinstance(f.spec.item, Map):
                lines.append(f"{head}list of map ({f.spec.min_len}..{f.spec.max_len}){opt}" + (f"  # {f.doc}" if f.doc else ""))
                lines.append(f.spec.item.describe(indent + 4))
            else:
                lines.append(f"{head}{f.spec.describe()}{opt}" + (f"  # {f.doc}" if f.doc else ""))
        for c in self.checks:
            if c.__doc__:
                lines.append(f"{pad}(rule) {c.__doc__.strip()}")
        return "\n".join(lines)


@dataclass
class Message:
    """A versioned request or reply. On the wire a message may carry ``v``; a version other
    than ``version`` is refused."""

    name: str
    body: Map
    version: int = 1
    doc: str = ""

    def validate(self, value) -> dict:
        if not isinstance(value, dict):
            raise BadInput(f"{self.name}: the message must be a map, got {type(value).__name__}", field="")
        v = value.get("v", self.version)
        if v != self.version:
            raise BadInput(f"{self.name}: schema version {v!r} is not supported (this service speaks v{self.version})",
                           field="v")
        body = {k: val for k, val in value.items() if k != "v"}
        try:
            return self.body.check(body, "")
        except BadInput as e:
            raise BadInput(f"{self.name}: {e.message}", **e.details) from None

    def describe(self) -> str:
        head = f"{self.name} v{self.version}" + (f": {self.doc}" if self.doc else "")
        return head + "\n" + (self.body.describe() or "  (no fields)")


@dataclass
class Endpoint:
    """One verb of a service: its request, its reply and what it does. ``waits``: the verb
    may wait for a person (an answer to a question); the service runs it on its pool of
    waiting requests, so that people thinking never hold the workers every other request
    needs. ``time_limit_s``: the request stops at a safe point past this
    (``unavailable``, cause ``time_limit``; ``shared.deadline``); verbs that wait for a person are
    bounded by their own ``timeout`` instead."""

    verb: str
    request: Message
    reply: Message
    doc: str = ""
    waits: bool = False
    time_limit_s: float = 600.0


def _in_range(value, lo, hi, path: str):
    if lo is not None and value < lo:
        _fail(path, f"must be >= {lo}, got {value}")
    if hi is not None and value > hi:
        _fail(path, f"must be <= {hi}, got {value}")
    return value


def _range(lo, hi) -> str:
    if lo is None and hi is None:
        return ""
    return f" in [{'-inf' if lo is None else lo}, {'inf' if hi is None else hi}]"
