"""Contract of the PSS model service (``services/pss``): named Proto-symbol Spaces.

Keys: ``<prefix>/pss/<verb>`` for requests; ``<prefix>/events/pss/space`` for changes.
"""

from __future__ import annotations

from schemas.base import (
    NAME_PATTERN,
    AnyMap,
    Array,
    Bool,
    Bytes,
    Endpoint,
    F,
    Float,
    Int,
    List,
    Map,
    MapOf,
    Message,
    Str,
)
from schemas.common import CLIP, DAMAGED, name
from shared.bus.wirefiles import FILE_PATTERN, READING_OPTIONS
from shared.errors import BadInput

SERVICE = "pss"
MAX_CLIPS = 2000

SPACE = name("space name: letters, digits, '_', '.', '-' (never a path)")
SYMBOL = F(Str(max_len=64), "a proto-symbol's name or label")

PARAMS = Map({
    "n_states": F(Int(1, 100), "HMM states per proto-symbol"),
    "fps": F(Float(1.0, 1000.0), "frame rate the clips are resampled to"),
    "dim": F(Int(1, 20), "dimension of the space"),
    "covariance_type": F(Str(choices=("diag", "full")), "HMM output covariance"),
    "var_floor": F(Float(0.0), "variance floor"),
    "backend": F(Str(choices=("banded", "hmmlearn")), "HMM trainer"),
    "n_iter": F(Int(1, 1000), "Baum-Welch iteration cap"),
    "group_by": F(Str(choices=("clip", "label")), "one proto-symbol per clip or per label"),
    "recognition_var_ceiling": F(Float(0.0), "state variances capped at this value when recognising (absent: none, "
                                             "a space saved before it)", required=False),
    "recognition_pose_floor": F(Float(0.0), "state variances of the position group's pose outputs raised to at least "
                                            "this value when recognising (absent: none, a space saved before it)",
                                required=False),
})

SYMBOL_ROW = Map({"name": F(Str(max_len=64)), "label": F(Str(max_len=64))})

INFO = Map({
    "space": SPACE,
    "n_proto_symbols": F(Int(0), "number of proto-symbols"),
    "labels": F(List(Str(max_len=64), max_len=MAX_CLIPS), "distinct labels, sorted"),
    "proto_symbols": F(List(SYMBOL_ROW, max_len=MAX_CLIPS), "name and label of every proto-symbol, in point order"),
    "points": F(Array(shape=(None, None)), "the proto-symbols' points (N x dim)"),
    "params": F(PARAMS, "build parameters"),
    "n_features": F(Int(1), "HMM output dimension"),
    "sensor_channels": F(List(Str(max_len=64), max_len=1000), "sensor channels modelled with the motion"),
    "stress": F(Float(0.0), "raw MDS stress"),
    "stress1": F(Float(0.0), "Kruskal stress-1"),
    "mds_converged": F(Bool()),
    "hmm_converged": F(Int(0), "how many HMMs met the convergence tolerance"),
    "format": F(Str(max_len=64), "the space file's format (mirrorcoach.space/1 or /2)", required=False),
    "recognition": F(Str(max_len=400), "how recognition decides a label in this space", required=False),
    "open_set": F(Str(max_len=400), "how recognition decides 'none of these' in this space", required=False),
    "rejects": F(Bool(), "whether any open-set test can say 'none of these' (false: too few known motions to "
                         "calibrate on, every motion gets its nearest label)", required=False),
})

NEAREST = Map({"name": F(Str(max_len=64)), "label": F(Str(max_len=64)), "distance": F(Float(0.0), "eq. 2.4 distance")})


CLIP_FILE = Map({
    "name": F(Str(pattern=FILE_PATTERN, max_len=68), "the file's name: NAME.amc, NAME.bvh or NAME.npz (never a path)"),
    "data": F(Bytes(), "the file's bytes"),
    "skeleton": F(Bytes(), "an AMC file's skeleton: the ASF file's bytes", required=False),
})

#: how clip files are read (the CLI's --units, --up, --translations; docs/files.md); the
#: readers refuse a value they do not know, naming the ones they do
READING = {k: F(Str(max_len=16), f"clip files' {k} (default: read off the file)", required=False)
           for k in READING_OPTIONS}


def _clips_or_files(req: dict, path: str):
    """exactly one of clips and files is given."""
    if (req["clips"] is None) == (req["files"] is None):
        raise BadInput("recognize: give exactly one of clips and files", field="clips")


def _point_or_mix(req: dict, path: str):
    """exactly one of point and mix is given."""
    if (req["point"] is None) == (req["mix"] is None):
        raise BadInput("generate: give exactly one of point and mix", field="point")


BUILD = Endpoint(
    "build",
    Message("pss.build", Map({
        "space": SPACE,
        "clips": F(List(CLIP, min_len=1, max_len=MAX_CLIPS), "the database D; every clip needs a label"),
        "n_states": F(Int(1, 100), "HMM states (default: half the shortest clip's frames, 2..15)", required=False),
        "dim": F(Int(1, 20), "dimension of the space", required=False, default=3),
        "fps": F(Float(1.0, 240.0), "resample the clips to this frame rate", required=False, default=30.0),
        "covariance_type": F(Str(choices=("diag", "full")), required=False, default="diag"),
        "group_by": F(Str(choices=("clip", "label")), required=False, default="clip"),
        "pose_floor": F(Float(0.0), "recognition's variance floor on the pose outputs, for a space that recognises "
                                    "styles it does not hold (absent: none)", required=False),
        "open_set": F(Bool(), "false: a space for association and generation only: recognition's open-set tests "
                              "(the novelty model, the discriminant ratio) are not fitted, its 'none of these' is "
                              "the distance rule alone", required=False, default=True),
        "replace": F(Bool(), "replace an existing space of that name (a space this same request built, unchanged "
                             "since, is kept as it is: a build is deterministic)", required=False, default=False),
    }), doc="build a space from clips (eq. 2.5)"),
    Message("pss.build.reply", INFO),
    "Build a named space from clips (eq. 2.5); fails with conflict if it exists and replace is false.",
)

ADD = Endpoint(
    "add",
    Message("pss.add", Map({
        "space": SPACE,
        "clips": F(List(CLIP, min_len=1, max_len=MAX_CLIPS), "clips to add as new proto-symbols"),
        "as_one": F(Str(pattern=NAME_PATTERN, max_len=64), "add all clips as the repetitions of one proto-symbol of this name",
                    required=False),
        "rebuild": F(Bool(), "true: embed every point again (eq. 2.5); false: place the new points among the fixed "
                             "ones and extend the distances (N per clip), the rest unchanged (not with as_one)",
                     required=False, default=True),
    }), doc="add proto-symbols (and rebuild the space, or place them)"),
    Message("pss.add.reply", INFO),
    "Add clips as proto-symbols: rebuild the space's points, or place the new ones among them.",
)

RECOGNIZE = Endpoint(
    "recognize",
    Message("pss.recognize", Map({
        "space": SPACE,
        "clips": F(List(CLIP, min_len=1, max_len=50), "one clip, or the repetitions of one trial", required=False),
        "files": F(List(CLIP_FILE, min_len=1, max_len=50), "the same as clip files, unread (the service reads them)",
                   required=False),
        **READING,
        "top": F(Int(1, 100), "how many nearest proto-symbols to return", required=False, default=5),
    }, checks=[_clips_or_files]), doc="place a motion in the space (eq. 2.6)"),
    Message("pss.recognize.reply", Map({
        "space": SPACE,
        "label": F(Str(max_len=64), "the recognised class; absent when the motion is none of the space's classes",
                   required=False),
        "known": F(Bool(), "false: the motion is none of the space's classes (open-set rejection)", required=False,
                   default=True),
        "nearest_label": F(Str(max_len=64), "the nearest class on the recognition channels (eq. 2.4, and the discriminant "
                           "where every class has two or more proto-symbols); the label unless the motion is none of them",
                           required=False),
        "confidence": F(Float(0.0, 1.0), "calibrated probability of nearest_label among the space's classes",
                        required=False),
        "novelty": F(Float(0.0), "distance from the known motions relative to the open-set threshold (> 1: unknown)",
                     required=False),
        "rejected_by": F(List(Str(choices=("distance", "ratio", "model")), max_len=3),
                         "the open-set tests that said none of these (only when known is false)", required=False),
        "label_in_space": F(Str(max_len=64), "label of the nearest point in the space"),
        "point": F(Array(shape=(None,)), "the motion's point"),
        "nearest": F(List(NEAREST, max_len=100), "nearest proto-symbols, nearest first"),
        "stress": F(Float(0.0), "out-of-sample stress of the placement"),
        "seconds": F(Float(0.0), "library time"),
        "another_skeleton": F(Bool(), "true: the clips are on another studio's skeleton, read by where its body's parts "
                              "are (their joints' positions mapped onto the space's), not by joint angles",
                              required=False, default=False),
    })),
    "Recognise a clip (or several repetitions) as a point, with its nearest proto-symbols.",
)

GENERATE = Endpoint(
    "generate",
    Message("pss.generate", Map({
        "space": SPACE,
        "point": F(Array(shape=(None,)), "a point of the space (inside or outside the hull)", required=False),
        "mix": F(MapOf(Str(max_len=64), Float(-100.0, 100.0), min_len=1, max_len=MAX_CLIPS),
                 "proto-symbol name or label -> weight, summing to 1", required=False),
        "method": F(Str(choices=("expected", "monte_carlo")), "trajectory method", required=False, default="expected"),
        "frames": F(Int(2, 100_000), "length of the motion (default: expected durations)", required=False),
        "seed": F(Int(0, 2**32 - 1), "seed of the Monte Carlo sampling", required=False, default=0),
        "name": F(Str(pattern=NAME_PATTERN, max_len=64), "name of the generated clip", required=False, default="generated"),
    }, checks=[_point_or_mix]), doc="generate a motion from a point or a mix (eq. 2.7, 4.1)"),
    Message("pss.generate.reply", Map({
        "space": SPACE,
        "clip": F(CLIP, "the generated motion, with the space's skeleton"),
        "weights": F(Array(shape=(None,)), "weight of every proto-symbol"),
        "point": F(Array(shape=(None,)), "the point generated from"),
    })),
    "Generate a motion from a point or from proto-symbol weights.",
)

ASSOCIATE = Endpoint(
    "associate",
    Message("pss.associate", Map({
        "space": SPACE,
        "clip": F(CLIP, "the partial pattern"),
        "missing": F(Str(choices=("sensor", "frames")), "what is missing: the sensor channels or the end of the motion",
                     required=False, default="sensor"),
        "method": F(Str(choices=("expected", "monte_carlo")), required=False, default="expected"),
        "seed": F(Int(0, 2**32 - 1), required=False, default=0),
        "weighting": F(Str(choices=("distance", "affine", "inverse_distance")),
                       "the proto-symbols' weights: from the motion's eq. 2.4 distances to them (convex), or from its "
                       "point, exact affine (may extrapolate) or convex inverse-distance; absent: distance for "
                       "missing sensor channels, affine for missing frames",
                       required=False),
        "whole": F(Bool(), "false: leave the whole generated pattern out of the reply (missing sensor channels "
                           "only: the aligned channels are the answer; saves generating it)",
                   required=False, default=True),
    }), doc="the whole pattern from a partial one (eq. 2.8)"),
    Message("pss.associate.reply", Map({
        "space": SPACE,
        "label": F(Str(max_len=64)),
        "point": F(Array(shape=(None,))),
        "whole": F(CLIP, "the whole generated pattern (absent when the request said whole: false)",
                   required=False),
        "aligned": F(CLIP, "the missing channels estimated on the clip's own frames", required=False),
        "progress": F(Float(0.0, 1.0), "how far through the motion the partial clip reaches", required=False),
        "reach": F(Float(0.0), "distance to the nearest proto-symbol over the 95th percentile of the proto-symbols' "
                               "own nearest-neighbour distances", required=False),
        "extrapolating": F(Bool(), "reach above 1: the estimate goes beyond what the space learnt", required=False),
    })),
    "Associate: the whole pattern (motion and sensor, or the rest of the motion) from a partial one.",
)

DISTANCE = Endpoint(
    "distance",
    Message("pss.distance", Map({"space": SPACE, "a": SYMBOL, "b": SYMBOL}), doc="eq. 2.4 between two proto-symbols"),
    Message("pss.distance.reply", Map({"space": SPACE, "a": F(Str(max_len=64)), "b": F(Str(max_len=64)),
                                       "distance": F(Float(0.0), "eq. 2.4 distance")})),
    "Distance (eq. 2.4) between two proto-symbols of a space.",
)

INFO_EP = Endpoint(
    "info",
    Message("pss.info", Map({"space": SPACE})),
    Message("pss.info.reply", INFO),
    "Everything about one space: proto-symbols, points, parameters, stress.",
)

LIST = Endpoint(
    "list",
    Message("pss.list", Map({})),
    Message("pss.list.reply", Map({
        "spaces": F(List(Map({"space": SPACE, "n_proto_symbols": F(Int(0)), "labels": F(List(Str(max_len=64), max_len=MAX_CLIPS)),
                              "dim": F(Int(1)), "stress1": F(Float(0.0))}), max_len=10_000)),
        "interrupted": F(List(Map({"space": SPACE, "operation": F(Str(max_len=32)), "started": F(Float(0.0))}),
                              max_len=10_000), "builds or adds that never finished (the service stopped mid-way)"),
        "damaged": DAMAGED,
    })),
    "Every space, any build that was interrupted, and any space file that cannot be read back.",
)

DELETE = Endpoint(
    "delete",
    Message("pss.delete", Map({"space": SPACE,
                               "missing_ok": F(Bool(), "a space that does not exist is no error: deleted is false",
                                               required=False, default=False)})),
    Message("pss.delete.reply", Map({"space": SPACE, "deleted": F(Bool())})),
    "Delete a space (its file too).",
)

ENDPOINTS = {e.verb: e for e in (BUILD, ADD, RECOGNIZE, GENERATE, ASSOCIATE, DISTANCE, INFO_EP, LIST, DELETE)}

EVENTS = {
    "space": Message("pss.event.space", Map({
        "space": SPACE,
        "change": F(Str(choices=("built", "added", "deleted")), "what happened"),
        "n_proto_symbols": F(Int(0)),
        "info": F(AnyMap(), "the space's info after the change (absent on delete)", required=False),
    }), doc="published on <prefix>/events/pss/space when a space changes"),
}
