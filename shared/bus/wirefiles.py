"""A clip's files packed raw for the bus, and read back where they arrive: the command line
sends the files as they are (:func:`wire_file`: nothing here imports numpy at import time, so
``mirrorcoach space recognize`` starts without it) and the pss service reads them once
(:func:`read_wire_files`, with the readers of :mod:`shared.io`)."""

from __future__ import annotations

import re
from pathlib import Path

from shared.bus.codec import DEFAULT_MAX_PAYLOAD
from shared.errors import BadInput, ClipFormatError
from shared.motion.clipfiles import find_skeleton

#: what the bus accepts as a clip file's name: a plain name with a clip suffix (never a path)
FILE_PATTERN = r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}\.(amc|bvh|npz|AMC|BVH|NPZ)"
#: how clip files are read (the CLI's root options); the readers check the values (shared/io/)
READING_OPTIONS = ("units", "up", "translations")



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


def read_wire_files(files: list[dict], reading: dict | None = None) -> list:
    """The clips of :func:`wire_file` entries, read as :func:`shared.io.load_clip` reads files
    (``reading``: units, up, translations), from a private temporary folder."""
    import tempfile

    from shared.io import load_clip  # the package's reader (this module is one of its parts)

    reading = {k: v for k, v in (reading or {}).items() if v is not None}
    clips = []
    with tempfile.TemporaryDirectory(prefix="mc-files-") as tmp:
        for i, f in enumerate(files):
            if not re.fullmatch(FILE_PATTERN, f["name"]):
                raise BadInput(f"files[{i}].name: {f['name']!r} is not a clip file name (NAME.amc, .bvh or .npz)",
                               field=f"files[{i}].name")
            folder = Path(tmp) / str(i)
            folder.mkdir()
            path = folder / f["name"]
            path.write_bytes(f["data"])
            skeleton = None
            if path.suffix.lower() == ".amc":
                if f.get("skeleton") is None:
                    raise BadInput(f"files[{i}]: an AMC file needs its skeleton (the ASF file's bytes)",
                                   field=f"files[{i}].skeleton")
                skeleton = folder / "skeleton.asf"  # read once per content (shared.io.load_skeleton)
                skeleton.write_bytes(f["skeleton"])
            try:
                clips.append(load_clip(path, skeleton=skeleton, **reading))
            except ClipFormatError as e:  # name the user's file, not the temporary copy
                raise BadInput(f"{f['name']}: {e.reason}", field=f"files[{i}]") from None
    return clips
