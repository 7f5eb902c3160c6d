"""Contract of the capture service (``services/capture``): takes recorded from a live motion
capture source (BVH motion lines over TCP) or from clips replayed through the same path, their
frames published as they arrive, and their repetitions of a target found.

Keys: ``<prefix>/capture/<verb>``; frames in blocks on ``<prefix>/events/capture/frames``, every
change of a take's state on ``<prefix>/events/capture/take``.
"""

from __future__ import annotations

from schemas.base import NAME_PATTERN, Array, Bool, Endpoint, F, Float, Int, List, Map, Message, Str
from schemas.common import CLIP, DAMAGED, name

SERVICE = "capture"
TAKE = name("the take's name (its file: <take>.bvh in the service's data folder)")
MAX_REPLAY = 50  # clips one replay may play, one per connection

STATE = F(Str(choices=("recording", "done", "failed")), "recording, done (the file is written) or failed")

TAKE_INFO = Map({
    "take": TAKE,
    "state": STATE,
    "source": F(Str(max_len=300), "where the frames come from: tcp://HOST:PORT, or replay of N clip(s)"),
    "frames": F(Int(0), "frames recorded so far"),
    "seconds": F(Float(0.0), "the take's duration so far"),
    "events": F(List(Str(max_len=1000), max_len=1000), "what happened on the way: dropped lines, missing "
                                                       "frames, a stop, a reconnection, a skeleton change"),
    "dropped": F(Int(0), "malformed frame lines dropped"),
    "skipped": F(Int(0), "frames the source left out (gaps)"),
    "reconnects": F(Int(0), "times the source came back"),
    "ended": F(Str(max_len=1000), "why the take ended (empty while recording)"),
    "error": F(Str(max_len=4000), "why the take failed", required=False),
    "last_frame_at": F(Float(0.0), "unix time the last frame arrived", required=False),
    "ended_at": F(Float(0.0), "unix time the take ended", required=False),
})

SPACE = F(Str(pattern=NAME_PATTERN, max_len=64), "a space of the pss service holding the target's motion and "
          "others: a repetition is a stretch the space names the target's motion (instead of the background check; "
          "each stretch recognised through the pss service; a take's `segment` for the same target uses the space it "
          "was recorded with when given none)", required=False)
LABEL = F(Str(max_len=64), "with space: the target's motion in it (default: the target's own label, else what the "
          "space recognises the target as)", required=False)

SEGMENT_REPLY = Map({
    "take": TAKE,
    "verdict": F(Str(max_len=500), "the expected repetitions found, fewer, more, or not the target"),
    "expected": F(Int(1, 1000), "repetitions expected", required=False),
    "repetitions": F(List(Map({
        "start": F(Float(0.0), "seconds from the take's start"),
        "end": F(Float(0.0), "seconds from the take's start"),
        "cost": F(Float(0.0), "distance from the target, as shapes"),
        "confidence": F(Float(0.0, 1.0), "how far its ratio (the cohort's, or with a space the space's) is below "
                        "its limit"),
        "cohort": F(Float(0.0), "cost against the target / against the nearest other motion; with a space, the "
                    "recognition distance to the target's motion / to the nearest other", required=False),
    }), max_len=1000)),
    "notes": F(List(Str(max_len=500), max_len=20), "what the segmentation noticed (the target's motion as the space "
               "recognised it)", required=False, default=list),
    "clips": F(List(CLIP, max_len=1000), "the repetitions cut from the take, in order"),
})

RECORD = Endpoint(
    "record",
    Message("capture.record", Map({
        "take": TAKE,
        "source": F(Str(max_len=300), "tcp://HOST:PORT of a live BVH stream (a capture suit, `capture serve`)",
                    required=False),
        "replay": F(List(CLIP, min_len=1, max_len=MAX_REPLAY), "clips played on a loopback port through the same "
                    "path as a live source, one per connection, all into the take (instead of source)", required=False),
        "speed": F(Float(0.1, 100.0), "a replay played this many times faster than its clips' rate (their time "
                   "stamps unchanged)", required=False, default=1.0),
        "skeleton": F(Str(max_len=1_000_000), "a BVH header (HIERARCHY .. MOTION) the stream's lines follow, when "
                      "the source sends no header", required=False),
        "fps": F(Float(1.0, 1000.0), "the stream's frame rate when it sends none", required=False),
        "seconds": F(Float(0.1, 3600.0), "the take's longest duration", required=False, default=120.0),
        "idle": F(Float(0.1, 600.0), "seconds without a frame that end the take", required=False, default=2.0),
        "reconnect": F(Int(0, 100), "times to connect again when the source stops", required=False, default=0),
        "target": F(CLIP, "with expected: the take ends once that many repetitions of it are seen",
                    required=False),
        "expected": F(Int(1, 1000), "repetitions that end the take (with target)", required=False),
        "background": F(List(CLIP, max_len=200), "other motions a repetition must be nearer the target than (with "
                        "target): kept with the take while the service runs (its 16 latest), its `segment` for the "
                        "same target uses them when it is given none", required=False,
                        default=list),
        "check_every": F(Float(0.05, 60.0), "seconds of take between looks for the expected repetitions",
                         required=False, default=0.1),
        "space": SPACE,
        "label": LABEL,
        "replace": F(Bool(), "record over a finished take of that name", required=False, default=False),
    })),
    Message("capture.record.reply", TAKE_INFO),
    "Start recording a take in the background (a take of that name recording or kept: conflict); its "
    "frames are published as they arrive, `status` or the take event says when it ends.",
)

STATUS = Endpoint(
    "status",
    Message("capture.status", Map({"take": TAKE})),
    Message("capture.status.reply", TAKE_INFO),
    "A take's state, frames and events.",
)

STOP = Endpoint(
    "stop",
    Message("capture.stop", Map({"take": TAKE})),
    Message("capture.stop.reply", TAKE_INFO),
    "End a take being recorded (its frames are kept) and return its state.",
)

CLIP_OF = Endpoint(
    "clip",
    Message("capture.clip", Map({"take": TAKE})),
    Message("capture.clip.reply", Map({"take": TAKE, "clip": F(CLIP, "the take as recorded")})),
    "A finished take as a clip.",
)

SEGMENT = Endpoint(
    "segment",
    Message("capture.segment", Map({
        "take": TAKE,
        "target": F(CLIP, "the motion whose repetitions to find"),
        "expected": F(Int(1, 1000), "repetitions expected", required=False, default=5),
        "background": F(List(CLIP, max_len=200), "other motions a repetition must be nearer the target than",
                        required=False, default=list),
        "space": SPACE,
        "label": LABEL,
    })),
    Message("capture.segment.reply", SEGMENT_REPLY),
    "A finished take's repetitions of the target (shared/capture/segment.py), each with its confidence and "
    "cut as a clip.",
    time_limit_s=120.0,
)

LIST = Endpoint(
    "list",
    Message("capture.list", Map({})),
    Message("capture.list.reply", Map({"takes": F(List(TAKE_INFO, max_len=100_000)), "damaged": DAMAGED})),
    "Every take, recording or kept.",
)

ENDPOINTS = {e.verb: e for e in (RECORD, STATUS, STOP, CLIP_OF, SEGMENT, LIST)}
EVENTS = {
    "frames": Message("capture.event.frames", Map({
        "take": TAKE,
        "first": F(Int(0), "the index of the block's first frame in the take"),
        "fps": F(Float(0.0), "frames per second (0 when the stream has not said)"),
        "data": F(Array(shape=(None, None), max_elements=10_000_000), "frames x channels as the stream sent them"),
    }), doc="the frames of a take being recorded, in blocks as they arrive"),
    "take": Message("capture.event.take", TAKE_INFO, doc="a take started, ended or failed"),
}
