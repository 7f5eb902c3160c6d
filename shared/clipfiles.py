"""Clip files as they lie on disk, without reading them: where an AMC file's skeleton is, and
a clip's files packed raw for the bus (the pss service reads them with
:func:`shared.io.wire.read_wire_files`).

Nothing here imports numpy: ``mirrorcoach space recognize`` sends the files as they are and
starts in well under 150 ms (issue 11); the reading happens once, in the service.
"""

from __future__ import annotations

import re
from pathlib import Path

from shared.codec import DEFAULT_MAX_PAYLOAD
from shared.errors import ClipFormatError

#: what the bus accepts as a clip file's name: a plain name with a clip suffix (never a path)
FILE_PATTERN = r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}\.(amc|bvh|npz|AMC|BVH|NPZ)"
#: how clip files are read (the CLI's root options); the readers check the values (shared/io/)
READING_OPTIONS = ("units", "up", "translations")


def find_skeleton(amc_path) -> Path:
    """The ASF of an AMC file in the usual layouts: beside it or in a sibling ``asf/`` folder
    (also one level up, as in ``amc/<class>/x.amc`` + ``asf/``), named after the actor:
    ``HDM_bd_..._120.amc`` -> ``HDM_bd.asf``; CMU ``07_01.amc`` -> ``07.asf``."""
    amc_path = Path(amc_path)
    stem = amc_path.stem
    names = []
    m = re.match(r"^(HDM_[A-Za-z]+)_", stem)
    if m:
        names.append(m.group(1) + ".asf")
    m = re.match(r"^(\d+)_\d+$", stem)
    if m:
        names.append(m.group(1) + ".asf")
    names.append(stem + ".asf")
    parts = stem.split("_")
    for k in range(len(parts) - 1, 0, -1):
        names.append("_".join(parts[:k]) + ".asf")
    folders = [amc_path.parent, amc_path.parent / "asf", amc_path.parent.parent / "asf", amc_path.parent.parent.parent / "asf"]
    for folder in folders:
        for n in names:
            cand = folder / n
            if cand.is_file():
                return cand
    asfs = sorted(amc_path.parent.glob("*.asf"))
    if len(asfs) == 1:
        return asfs[0]
    raise ClipFormatError(amc_path, "no skeleton found: put the actor's .asf beside it or in a sibling asf/ folder, or pass --skeleton FILE")


def wire_name(name: str, max_len: int = 64) -> str:
    """A name the contracts accept (letters, digits, '_', '.', '-'; a letter or digit first)."""
    n = re.sub(r"[^A-Za-z0-9_.-]", "_", name or "clip")[:max_len]
    return n if n[:1].isalnum() else ("c" + n)[:max_len]


def _read_bytes(path: Path, limit: int) -> bytes:
    try:
        size = path.stat().st_size
        if size > limit:
            raise ClipFormatError(path, f"is {size} bytes, over the bus limit of {limit} bytes")
        return path.read_bytes()
    except FileNotFoundError:
        raise ClipFormatError(path, "no such file") from None
    except IsADirectoryError:
        raise ClipFormatError(path, "is a folder, not a clip file") from None
    except OSError as e:
        raise ClipFormatError(path, f"cannot be read ({e.strerror or e})") from None


def wire_file(path, skeleton=None, limit: int = DEFAULT_MAX_PAYLOAD) -> dict:
    """One clip file for the bus, unread: ``{name, data[, skeleton]}`` (an AMC file carries its ASF)."""
    path = Path(path)
    if path.suffix.lower() not in (".amc", ".bvh", ".npz"):
        raise ClipFormatError(path, f"unknown clip format {path.suffix!r} (expected one of .amc, .bvh, .npz)")
    out = {"name": wire_name(path.stem, 59) + path.suffix.lower(), "data": _read_bytes(path, limit)}
    if path.suffix.lower() == ".amc":
        out["skeleton"] = _read_bytes(Path(skeleton) if skeleton is not None else find_skeleton(path), limit)
    return out
