"""NPZ: a clip's raw arrays with its channel names, groups and skeleton (no pickle)."""

from __future__ import annotations

import json
import zipfile
from pathlib import Path

import numpy as np

from shared.errors import ClipFormatError
from shared.motion.clip import Clip
from shared.motion.skeleton import Skeleton

FORMAT = "mirrorcoach.clip/1"


class Stacked:
    """An array of ``np.stack(parts)`` that :func:`savez_stacked` writes part by part, never
    stacked in memory (a space of 3,000 proto-symbols: 0.18 GB of HMM means and variances)."""

    def __init__(self, parts):
        self.parts = list(parts)
        first = np.asarray(self.parts[0])
        self.shape, self.dtype = (len(self.parts),) + first.shape, first.dtype


def savez_stacked(f, arrays: dict) -> None:
    """``np.savez(f, **arrays)`` where a value may be :class:`Stacked`: the same file
    (``np.load`` reads it back as the stacked array)."""
    with zipfile.ZipFile(f, mode="w", compression=zipfile.ZIP_STORED, allowZip64=True) as z:
        for key, value in arrays.items():
            with z.open(f"{key}.npy", "w", force_zip64=True) as out:
                if isinstance(value, Stacked):
                    np.lib.format.write_array_header_2_0(out, {"descr": np.lib.format.dtype_to_descr(value.dtype),
                                                               "fortran_order": False, "shape": value.shape})
                    for part in value.parts:
                        part = np.asarray(part, dtype=value.dtype)
                        if part.shape != value.shape[1:]:
                            raise ValueError(f"{key}: a part of shape {part.shape}, not {value.shape[1:]}")
                        out.write(np.ascontiguousarray(part).tobytes())
                else:
                    np.lib.format.write_array(out, np.asanyarray(value), allow_pickle=False)


def write_npz(clip: Clip, path) -> None:
    meta = {
        "format": FORMAT,
        "channels": clip.channels,
        "fps": clip.fps,
        "groups": clip.groups,
        "name": clip.name,
        "label": clip.label,
        "skeleton": None if clip.skeleton is None else clip.skeleton.to_json(),
    }
    with open(path, "wb") as f:
        np.savez_compressed(f, data=clip.data, meta=np.array(json.dumps(meta)))


#: what an NPZ clip may unpack to: a clip's data (200,000 frames x 1,000 channels is 1.6 GB:
#: the bus's own limits are far below) and its JSON header; checked before anything is inflated
MAX_DATA_BYTES = 512 * 1024 * 1024
MAX_META_BYTES = 16 * 1024 * 1024


#: :func:`npz_problem`'s answer for a file that is no zip archive at all
NOT_AN_ARCHIVE = "not an NPZ archive"


def npz_problem(path: Path, limits: dict[str, int], total: int, max_members: int = 4096) -> str | None:
    """Why the NPZ archive at ``path`` may not be read, or ``None``: checked from the zip's own
    directory and each array's header before numpy reads anything. Refused: a member that would
    inflate beyond its limit in ``limits`` (by member name, e.g. ``"data.npy"``) or all of them
    beyond ``total`` bytes (a zip bomb), more than ``max_members`` members, an array of Python
    objects (numpy would unpickle it), and an array whose header declares more bytes than its
    member holds (numpy allocates what the header declares before it reads: a header of a
    trillion elements in a file of a few bytes asked for 7 TiB and ended in ``MemoryError``)."""
    try:
        with zipfile.ZipFile(path) as zf:
            infos = zf.infolist()
            if len(infos) > max_members:
                return f"{len(infos)} arrays, more than the {max_members} allowed"
            for info in infos:
                limit = limits.get(info.filename)
                if limit is not None and info.file_size > limit:
                    return f"member {info.filename!r} unpacks to {info.file_size} bytes, over the limit of {limit} bytes"
            inflated = sum(i.file_size for i in infos)
            if inflated > total:
                return f"its arrays unpack to {inflated} bytes, over the limit of {total} bytes"
            for info in infos:
                if not info.filename.endswith(".npy"):
                    continue
                with zf.open(info) as f:
                    version = np.lib.format.read_magic(f)
                    read_header = (np.lib.format.read_array_header_1_0 if version == (1, 0)
                                   else np.lib.format.read_array_header_2_0)
                    shape, _, dtype = read_header(f)
                    start = f.tell()
                if dtype.hasobject:
                    return f"member {info.filename!r} holds Python objects (it would have to be unpickled)"
                declared = int(np.prod(shape, dtype=object)) * dtype.itemsize
                if declared > info.file_size - start:
                    return (f"member {info.filename!r} declares an array of shape {tuple(shape)} ({declared} bytes) "
                            f"but holds {info.file_size - start} bytes")
    except zipfile.BadZipFile:  # numpy would try it as a pickle, and say so
        return NOT_AN_ARCHIVE
    except (OSError, ValueError, EOFError, zipfile.LargeZipFile) as e:
        return f"unreadable NPZ archive ({type(e).__name__}: {e})"
    return None


def _check_archive(path: Path) -> None:
    """Refuse a clip file :func:`npz_problem` finds unsafe to read, or with more members than a clip."""
    why = npz_problem(path, {"data.npy": MAX_DATA_BYTES, "meta.npy": MAX_META_BYTES},
                      MAX_DATA_BYTES + MAX_META_BYTES, max_members=16)
    if why is not None:
        raise ClipFormatError(path, f"cannot read NPZ clip: {why}")


def _meta_field(path: Path, meta: dict, key: str, kind, what: str):
    value = meta.get(key)
    if not isinstance(value, kind) or isinstance(value, bool):
        raise ClipFormatError(path, f"NPZ clip header: {key!r} must be {what}, got {type(value).__name__} {value!r:.40}")
    return value


def read_npz(path, label: str | None = None) -> Clip:
    path = Path(path)
    if path.is_file():
        _check_archive(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            if "data" not in z or "meta" not in z:
                raise ClipFormatError(path, "not a mirrorcoach clip (needs arrays 'data' and 'meta')")
            data = np.array(z["data"], dtype=float)
            meta = json.loads(str(z["meta"]))
    except (OSError, ValueError, TypeError, zipfile.BadZipFile, json.JSONDecodeError) as e:
        raise ClipFormatError(path, f"cannot read NPZ clip: {e}") from None
    if not isinstance(meta, dict):
        raise ClipFormatError(path, f"NPZ clip header must be a JSON object, got {type(meta).__name__}")
    if meta.get("format") != FORMAT:
        raise ClipFormatError(path, f"unknown clip format {meta.get('format')!r:.60} (expected {FORMAT})")
    channels = _meta_field(path, meta, "channels", list, "a list of channel names")
    if not all(isinstance(c, str) for c in channels):
        raise ClipFormatError(path, "NPZ clip header: every channel name must be text")
    fps = float(_meta_field(path, meta, "fps", (int, float), "a number (frames per second)"))
    if not (np.isfinite(fps) and 0 < fps <= 10_000):
        raise ClipFormatError(path, f"NPZ clip header: fps {fps!r} is not a frame rate (0-10000)")
    groups = _meta_field(path, meta, "groups", dict, "a map of channel groups")
    if not all(isinstance(v, list) and all(isinstance(c, str) for c in v) for v in groups.values()):
        raise ClipFormatError(path, "NPZ clip header: every group must be a list of channel names")
    if data.ndim != 2 or data.shape[1] != len(channels):
        raise ClipFormatError(path, f"NPZ clip: data of shape {data.shape} for {len(channels)} channels")
    for key in ("name", "label"):
        if meta.get(key) is not None and not isinstance(meta[key], str):
            raise ClipFormatError(path, f"NPZ clip header: {key!r} must be text")
    try:
        sk = Skeleton.from_json(meta["skeleton"]) if meta.get("skeleton") else None
    except (KeyError, TypeError, ValueError, AttributeError, IndexError) as e:
        raise ClipFormatError(path, f"NPZ clip header: unreadable skeleton ({type(e).__name__}: {e})") from None
    return Clip(data=data, channels=list(channels), fps=fps, skeleton=sk,
                groups={k: list(v) for k, v in groups.items()}, name=meta.get("name") or path.stem,
                label=label if label is not None else meta.get("label"), source=str(path))
