"""Reading and writing clips: ASF/AMC, BVH and NPZ, chosen by file extension, in any studio's
conventions (units, up axis, root frame, position channels). Imports ``motion`` and ``errors``."""

from __future__ import annotations

import threading
from collections import OrderedDict
from pathlib import Path

from shared.errors import ClipFormatError
from shared.io.asf_amc import find_skeleton, read_amc, read_asf, write_amc
from shared.io.bvh import read_bvh, write_bvh
from shared.io.conventions import check_reading
from shared.io.npz import read_npz, write_npz
from shared.motion.clip import Clip

CLIP_SUFFIXES = (".amc", ".bvh", ".npz")
#: a clip file is read whole: a larger one is refused before reading (a 2 GB file took 4 GB of memory)
MAX_CLIP_FILE_BYTES = 512 * 1024 * 1024
ASF_CACHE_SIZE = 64
_ASF_CACHE: OrderedDict = OrderedDict()  # (the file's bytes, units) -> Skeleton, least recently used first
_ASF_LOCK = threading.Lock()


def load_skeleton(path, units: str | None = None):
    """:func:`read_asf`, once per file content and unit: a performer's clips share one skeleton
    (and its compiled kinematics). Keyed by content, not path, so an edited file is read again
    and a service that receives skeletons as bytes (:mod:`shared.motion.clipfiles`) reuses them;
    bounded, so a long-running service does not grow. The key is the bytes themselves (a few KB
    each; hashlib's OpenSSL would cost every command's start 4 ms)."""
    try:
        key = (Path(path).read_bytes(), units)
    except OSError as e:
        raise ClipFormatError(path, f"cannot read file: {e.strerror or e}") from None
    with _ASF_LOCK:
        if key in _ASF_CACHE:
            _ASF_CACHE.move_to_end(key)
            return _ASF_CACHE[key]
    sk = read_asf(path, units=units)
    with _ASF_LOCK:
        _ASF_CACHE[key] = sk
        while len(_ASF_CACHE) > ASF_CACHE_SIZE:
            _ASF_CACHE.popitem(last=False)
    return sk


def load_clip(path, skeleton=None, label: str | None = None, *, units: str | None = None, up: str | None = None,
              translations: str | None = None) -> Clip:
    """Read a clip. For AMC the skeleton is found beside the file (see ``find_skeleton``)
    unless ``skeleton`` (a path or a Skeleton) is given. The label defaults to the name of
    the clip's parent folder. ``units``, ``up`` and ``translations`` override what the reader
    reads off the body (:mod:`shared.io.conventions`)."""
    path = Path(path)
    if not path.exists():
        raise ClipFormatError(path, "no such file")
    check_reading(path, units, up, translations)
    size = path.stat().st_size if path.is_file() else 0
    if size > MAX_CLIP_FILE_BYTES:
        raise ClipFormatError(path, f"is {size} bytes; clip files are read whole, up to "
                                    f"{MAX_CLIP_FILE_BYTES // 2**20} MiB (split the take)")
    suffix = path.suffix.lower()
    if suffix == ".amc":
        if skeleton is None:
            skeleton = find_skeleton(path)
        if up not in (None, "y"):
            raise ClipFormatError(path, "ASF/AMC bodies are read Y-up; --up z applies to BVH files")
        if not hasattr(skeleton, "joints"):
            skeleton = load_skeleton(skeleton, units=units)
        return read_amc(path, skeleton, label=label)
    if suffix == ".bvh":
        return read_bvh(path, label=label, units=units, up=up, translations=translations)
    if suffix == ".npz":
        return read_npz(path, label=label)
    raise ClipFormatError(path, f"unknown clip format {suffix!r} (expected one of {', '.join(CLIP_SUFFIXES)})")


def save_clip(clip: Clip, path) -> None:
    """Write a clip (format by suffix), atomically: a temporary file beside it, then a rename,
    so a reader or a crash never sees half a file."""
    import os
    import uuid

    path = Path(path)
    writers = {".bvh": write_bvh, ".npz": write_npz, ".amc": write_amc}
    suffix = path.suffix.lower()
    if suffix not in writers:
        raise ClipFormatError(path, f"cannot write {suffix!r} (use .bvh, .npz or .amc)")
    tmp = path.with_name(f".{path.stem}.{uuid.uuid4().hex[:8]}.tmp{path.suffix}")
    try:
        writers[suffix](clip, tmp)
        os.replace(tmp, path)
    except OSError as e:
        raise ClipFormatError(path, f"cannot write file: {e.strerror or e}") from None
    except ClipFormatError as e:  # a writer names the file it wrote: the user's, not the temporary one
        if e.path != str(tmp):
            raise
        raise ClipFormatError(path, e.reason, e.line) from None
    finally:
        tmp.unlink(missing_ok=True)


def find_clips(paths) -> list[Path]:
    """Every clip file under the given files or folders, sorted."""
    out: list[Path] = []
    for p in paths:
        p = Path(p)
        if p.is_dir():
            out.extend(sorted(q for q in p.rglob("*") if q.suffix.lower() in CLIP_SUFFIXES))
        elif p.is_file():
            out.append(p)
        else:
            raise ClipFormatError(p, "no such file or folder")
    return out


class LazyClips:
    """Clip files as a sequence whose items are read when taken and not kept: a space built
    from thousands of files (:meth:`ProtoSymbolSpace.build`) reads each twice instead of
    holding them all (3,000 game-studio clips are 0.56 GB of numbers). ``read(path)`` reads one
    (default :func:`load_clip`); ``on_read(index)`` is called after each read."""

    def __init__(self, files, read=None, on_read=None):
        self.files = [Path(f) for f in files]
        self.read = read or load_clip
        self.on_read = on_read

    def __len__(self) -> int:
        return len(self.files)

    def __getitem__(self, i: int) -> Clip:
        clip = self.read(self.files[i])
        if self.on_read is not None:
            self.on_read(i)
        return clip


__all__ = ["LazyClips", "load_clip", "save_clip", "find_clips", "load_skeleton", "read_asf", "read_amc", "write_amc",
           "read_bvh", "write_bvh", "read_npz", "write_npz", "find_skeleton"]
