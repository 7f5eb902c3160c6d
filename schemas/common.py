"""Pieces every service's contract uses: names, the clip on the wire, errors."""

from __future__ import annotations

import json

import numpy as np

from schemas.base import NAME_PATTERN, AnyMap, Array, F, Float, List, Map, Message, Str
from shared.errors import BadInput

CHANNEL_PATTERN = r"[A-Za-z0-9_][A-Za-z0-9_.:-]{0,63}"
MAX_FRAMES = 200_000
MAX_CHANNELS = 1_000


def name(doc: str) -> F:
    return F(Str(pattern=NAME_PATTERN, max_len=64), doc)


#: a list verb's things whose saved files cannot be read back (shared/io/saved.py), beside the readable ones
DAMAGED = F(List(Map({"kind": F(Str(max_len=32), "what it is: other, learner, estimate, coaching session, take, space"),
                      "name": F(Str(max_len=64)),
                      "message": F(Str(max_len=2000), "what is wrong with its file and what to do (the file is kept)")}),
                 max_len=100_000), "saved files that cannot be read back", required=False, default=list)


def _clip_columns(clip: dict, path: str):
    """data has one column per channel; sensor channels are among the channels."""
    cols = clip["data"].shape[1]
    if cols != len(clip["channels"]):
        raise BadInput(f"{path}: data has {cols} columns but {len(clip['channels'])} channel names",
                       field=f"{path}.data")
    if len(set(clip["channels"])) != len(clip["channels"]):
        raise BadInput(f"{path}: duplicate channel names", field=f"{path}.channels")
    unknown = set(clip["sensor"]) - set(clip["channels"])
    if unknown:
        raise BadInput(f"{path}: sensor channels {sorted(unknown)[:3]} are not among the channels", field=f"{path}.sensor")


CLIP = Map(
    {
        "name": name("clip name"),
        "label": F(Str(pattern=NAME_PATTERN, max_len=64), "motion class (the proto-symbol's label)", required=False),
        "fps": F(Float(min=1.0, max=1000.0), "frame rate, frames per second"),
        "channels": F(List(Str(pattern=CHANNEL_PATTERN, max_len=64), min_len=1, max_len=MAX_CHANNELS),
                      "channel names, e.g. rhumerus.rx"),
        "data": F(Array(shape=(None, None), min_shape=(2, 1), max_elements=MAX_FRAMES * 100),
                  "frames x channels, degrees for angles"),
        "sensor": F(List(Str(pattern=CHANNEL_PATTERN, max_len=64), max_len=MAX_CHANNELS),
                    "which channels are sensor channels (torques, centre of gravity)", required=False, default=list),
        "skeleton": F(Str(max_len=2_000_000), "skeleton as JSON (shared.motion.skeleton.Skeleton.to_json)", required=False),
    },
    checks=[_clip_columns],
    doc="a motion clip",
)

ERROR = Message("error", Map({
    "code": F(Str(choices=("bad_request", "not_found", "conflict", "unavailable", "internal")), "stable error code"),
    "message": F(Str(max_len=4000), "what went wrong, for a person"),
    "details": F(AnyMap(), "machine-readable context (field, limit, ...)", required=False, default=dict),
}), doc="the payload of every reply_err")


def clip_to_wire(clip, with_skeleton: bool = True) -> dict:
    """A :class:`shared.motion.clip.Clip` as a CLIP map."""
    d = {
        "name": clip.name or "clip",
        "fps": float(clip.fps),
        "channels": list(clip.channels),
        "data": np.ascontiguousarray(clip.data, dtype=np.float64),
        "sensor": clip.group("sensor"),
    }
    if clip.label:
        d["label"] = clip.label
    if with_skeleton and clip.skeleton is not None:
        d["skeleton"] = clip.skeleton.to_json()
    return d


def clip_from_wire(d: dict, skeleton=None):
    """A validated CLIP map as a Clip; ``skeleton`` is used when the message has none."""
    from shared.motion.clip import Clip
    from shared.motion.skeleton import Skeleton

    sk = skeleton
    if d.get("skeleton"):
        try:
            sk = Skeleton.from_json(d["skeleton"])
        except (ValueError, KeyError, TypeError, json.JSONDecodeError) as e:
            raise BadInput(f"clip {d['name']!r}: the skeleton is not valid skeleton JSON ({type(e).__name__}: {e})",
                           field="skeleton") from None
    sensor = list(d.get("sensor") or [])
    groups = {"motion": [c for c in d["channels"] if c not in sensor]}
    if sensor:
        groups["sensor"] = sensor
    return Clip(np.array(d["data"], dtype=np.float64), list(d["channels"]), float(d["fps"]), sk, groups,
                name=d["name"], label=d.get("label"))
