"""NPZ: a clip's raw arrays with its channel names, groups and skeleton (no pickle)."""

from __future__ import annotations

import json
import zipfile
from pathlib import Path

import numpy as np

from shared.clip import Clip
from shared.errors import ClipFormatError
from shared.skeleton import Skeleton

FORMAT = "mirrorcoach.clip/1"


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


def read_npz(path, label: str | None = None) -> Clip:
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            if "data" not in z or "meta" not in z:
                raise ClipFormatError(path, "not a mirrorcoach clip (needs arrays 'data' and 'meta')")
            data = np.array(z["data"], dtype=float)
            meta = json.loads(str(z["meta"]))
    except (OSError, ValueError, zipfile.BadZipFile, json.JSONDecodeError) as e:
        raise ClipFormatError(path, f"cannot read NPZ clip: {e}") from None
    if meta.get("format") != FORMAT:
        raise ClipFormatError(path, f"unknown clip format {meta.get('format')!r} (expected {FORMAT})")
    sk = Skeleton.from_json(meta["skeleton"]) if meta.get("skeleton") else None
    return Clip(data=data, channels=list(meta["channels"]), fps=float(meta["fps"]), skeleton=sk,
                groups={k: list(v) for k, v in meta["groups"].items()}, name=meta.get("name") or path.stem,
                label=label if label is not None else meta.get("label"), source=str(path))
