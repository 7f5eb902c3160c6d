"""The capture service: records takes from a live motion capture source, or from clips replayed
through the same path, publishes their frames as they arrive and finds the repetitions of a
target in them (contract: ``schemas/capture.py``).

The recording is :func:`shared.capture.stream.record` in a thread per take (at most
``MAX_RECORDING`` at once); a replay is a :class:`shared.capture.stream.ReplaySource` on a
loopback port the recorder connects to like any source. Frames go out in blocks of at most
``BLOCK`` seconds. A take's state is kept in ``<take>.json`` beside its ``<take>.bvh`` in
``$MIRRORCOACH_HOME/data/capture``, so a restarted service lists what it recorded; a take the
service stopped under is marked failed, never left recording.
"""

from __future__ import annotations

import json
import os
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from schemas import capture as contract
from schemas.common import clip_from_wire, clip_to_wire
from shared.bus.config import Settings
from shared.bus.runtime import Service
from shared.errors import BadInput, Conflict, DamagedFile, MirrorcoachError, NotFound, Unavailable
from shared.io.atomic import atomic_write
from shared.io.saved import read_back

MAX_RECORDING = 4  # takes recorded at once
BLOCK = 0.1  # seconds of frames in one published block


class _Recording:
    """One take being recorded: its state (``TAKE_INFO``), frames not yet published, a stop."""

    def __init__(self, info: dict):
        self.info = info
        self.stop = threading.Event()
        self.block: list[list[float]] = []
        self.first = 0
        self.sent_at = time.monotonic()
        self.thread: threading.Thread | None = None


class _SpaceOnBus:
    """A space of the pss service, as segmentation asks it (:class:`shared.capture.naming.SpaceNamer`
    over the bus): its labels and shortest readable clip once, each stretch recognised by a
    ``pss/recognize`` request (its nearest ``TOP`` proto-symbols: enough to tell whether the
    nearest is the target's)."""

    TOP = 100

    def __init__(self, client, space: str):
        from shared.pss.symbol import shortest_seconds

        self.client, self.space = client, space
        info = client.request("pss", "info", {"space": space}, timeout=30)
        self.labels = [row["label"] for row in info["proto_symbols"]]
        self.shortest = shortest_seconds(info["params"]["n_states"], info["params"]["fps"])
        self.sensor_channels = list(info["sensor_channels"])

    def _recognize(self, clip) -> dict:
        return self.client.request("pss", "recognize", {"space": self.space, "clips": [clip_to_wire(clip)],
                                                        "top": self.TOP}, timeout=30)

    def nearest(self, clip):
        near = self._recognize(clip)["nearest"]
        return np.asarray([n["label"] for n in near]), np.asarray([n["distance"] for n in near], float)

    def recognise(self, clip):
        r = self._recognize(clip)
        return r.get("label"), r.get("nearest_label", ""), float(r.get("confidence", 0.0))


def _warm() -> None:
    """Load the segmentation's compiled kernels and the feature code once at start, so that the
    first take's checks do not pay for it (a person waits on the first trial as on any other)."""
    from shared.capture import segment
    from shared.pss import features  # noqa: F401

    x = np.ascontiguousarray(np.random.default_rng(0).random((6, 6)))
    segment.subsequence_dtw(x)
    segment.global_dtw(x)


def _same(a, b) -> bool:
    """Two clips with the same channels, rate and frames."""
    return a.channels == b.channels and a.fps == b.fps and a.data.shape == b.data.shape and np.array_equal(a.data, b.data)


def make_service(settings: Settings | None = None) -> Service:
    settings = settings or Settings()
    _warm()
    root = settings.data_dir("capture")
    root.mkdir(parents=True, exist_ok=True)
    svc = Service(contract.SERVICE, contract.ENDPOINTS, contract.EVENTS, settings=settings)
    lock = threading.Lock()
    live: dict[str, _Recording] = {}
    cut: dict[str, tuple] = {}  # take -> (target, expected, clip, segmentation, (space, label)) found while recording it
    # take -> (target, the other motions and (space, label) it was recorded with): its segment's defaults
    grounds: dict[str, tuple] = {}

    def save(info: dict) -> None:
        atomic_write(root / f"{info['take']}.json", lambda f: f.write(json.dumps(info).encode()))

    def load(take: str) -> dict:
        p = root / f"{take}.json"
        if not p.exists():
            raise NotFound(f"no take {take!r}", take=take)
        with read_back(p, "take", take):
            return contract.TAKE_INFO.check(json.loads(p.read_text()), "take")

    # a take the service stopped under (killed while recording) is failed, never left recording
    for p in root.glob("*.json"):
        try:
            info = json.loads(p.read_text())
            if info.get("state") == "recording":
                save({**info, "state": "failed", "ended": "the capture service stopped while recording",
                      "error": "the capture service stopped while recording: its frames were only on the bus"})
        except (OSError, ValueError):
            continue

    def space_of(space: str | None):
        """The pss service's space of that name, as segmentation asks it (None: the cohort decides)."""
        return None if not space else _SpaceOnBus(svc.client(), space)

    def info_of(take: str) -> dict:
        with lock:
            rec = live.get(take)
            if rec is not None:
                return dict(rec.info)
        return load(take)

    def flush(rec: _Recording, fps: float) -> None:
        if rec.block:
            data = np.asarray(rec.block, dtype=np.float32)
            svc.publish("frames", {"take": rec.info["take"], "first": rec.first, "fps": fps, "data": data})
            rec.first += len(rec.block)
            rec.block = []
        rec.sent_at = time.monotonic()

    def run(rec: _Recording, req: dict, source: str, server, namer) -> None:
        from shared.capture.segment import until_repeated
        from shared.capture.stream import record

        take = rec.info["take"]
        frame_rate = [0.0]

        def on_frame(k: int, values: list[float], frame_time: float | None) -> None:
            frame_rate[0] = 1.0 / frame_time if frame_time else 0.0
            rec.block.append(values)
            with lock:
                rec.info["frames"] = k + 1
                rec.info["seconds"] = k * (frame_time or 0.0)
            if time.monotonic() - rec.sent_at >= BLOCK:
                flush(rec, frame_rate[0])

        until = target = header = None
        try:
            if req.get("target") is not None and req.get("expected"):
                target = clip_from_wire(req["target"])
                background = [clip_from_wire(c) for c in req.get("background") or []]
                with lock:
                    grounds[take] = (target, background, (req.get("space"), req.get("label")))
                    while len(grounds) > 16:
                        grounds.pop(next(iter(grounds)))
                until = until_repeated(target, req["expected"], background=background, space=namer, label=req.get("label"))
            if req.get("skeleton"):
                fd, name = tempfile.mkstemp(prefix=".header-", suffix=".bvh", dir=root)
                os.close(fd)
                header = Path(name)
                header.write_text(req["skeleton"], encoding="latin-1")
            result = record(source, root / f"{take}.bvh", seconds=req["seconds"], idle=req["idle"],
                            reconnect=req["reconnect"], skeleton=header, fps=req.get("fps"), until=until,
                            check_every=req["check_every"], on_frame=on_frame, stop_when=rec.stop, read=False)
            flush(rec, frame_rate[0])
            if until is not None and until.last is not None and until.last[0].n_frames == result.frames:
                with lock:  # the check that ended the take saw all of it: its cut is the take's
                    cut[take] = (target, req["expected"], *until.last, (req.get("space"), req.get("label")))
                    while len(cut) > 16:
                        cut.pop(next(iter(cut)))
            d = result.to_dict()
            final = {**rec.info, "state": "done" if result.frames else "failed", "frames": d["frames"],
                     "seconds": d["seconds"], "events": d["events"][-1000:], "dropped": d["dropped"],
                     "skipped": d["skipped"], "reconnects": d["reconnects"], "ended": d["ended"] or "ended"}
            now_unix, now = time.time(), time.monotonic()
            if result.last_frame is not None:
                final["last_frame_at"] = now_unix - (now - result.last_frame)
            if result.ended_at is not None:
                final["ended_at"] = now_unix - (now - result.ended_at)
            if not result.frames:
                final["error"] = f"no frames recorded ({d['ended']})"
        except MirrorcoachError as e:
            final = {**rec.info, "state": "failed", "ended": "failed", "error": e.message}
        except Exception as e:  # noqa: BLE001 - a recording thread must always leave a state behind
            final = {**rec.info, "state": "failed", "ended": "failed", "error": f"{type(e).__name__}: {e}"}
        finally:
            if server is not None:
                server.stop()
            if header is not None:
                header.unlink(missing_ok=True)
        save(final)
        with lock:
            live.pop(take, None)
        svc.publish("take", final)

    @svc.handler("record")
    def start(req):
        from shared.capture.stream import ReplaySource, parse_source

        take = req["take"]
        if (req.get("source") is None) == (req.get("replay") is None):
            raise BadInput("give either source (tcp://HOST:PORT) or replay (clips)", field="source")
        if req.get("expected") and req.get("target") is None:
            raise BadInput("expected repetitions end a take only with the target to find", field="target")
        if req.get("target") is not None and clip_from_wire(req["target"]).skeleton is None:
            raise BadInput("the target needs its skeleton to find its repetitions", field="target")
        namer = None
        if req.get("space"):  # asked now, so that a space or label it cannot use is refused before recording
            from shared.capture.naming import readable, target_label

            if req.get("target") is None:
                raise BadInput("a space tells the target's repetitions: give the target too", field="space")
            namer = space_of(req["space"])
            target = clip_from_wire(req["target"])
            readable(namer, target)  # the take has the target's channels
            req = {**req, "label": target_label(namer, target, req.get("label"))[0]}
        server = None
        if req.get("source") is not None:
            parse_source(req["source"])
            source = req["source"]
        else:
            clips = [clip_from_wire(c) for c in req["replay"]]
            if any(c.skeleton is None for c in clips):
                raise BadInput("replayed clips need their skeleton (a BVH header is sent first)", field="replay")
            server = ReplaySource(clips, host="127.0.0.1", connections=len(clips), speed=req["speed"]).start()
            source = server.address
            req = {**req, "reconnect": max(req["reconnect"], len(clips) - 1)}  # every clip, one after another
        with lock:
            cut.pop(take, None)
            if take in live:
                server and server.stop()
                raise Conflict(f"take {take!r} is being recorded", take=take)
            if (root / f"{take}.json").exists() and not req["replace"]:
                server and server.stop()
                raise Conflict(f"take {take!r} exists (replace=true records over it)", take=take)
            if len(live) >= MAX_RECORDING:
                server and server.stop()
                raise Unavailable(f"{MAX_RECORDING} takes are being recorded: stop one first", limit=MAX_RECORDING)
            shown = source if server is None else f"replay of {len(req['replay'])} clip(s)"
            rec = _Recording({"take": take, "state": "recording", "source": shown, "frames": 0, "seconds": 0.0,
                              "events": [], "dropped": 0, "skipped": 0, "reconnects": 0, "ended": ""})
            live[take] = rec
            save(rec.info)
        rec.thread = threading.Thread(target=run, args=(rec, req, source, server, namer), daemon=True,
                                      name=f"capture-{take}")
        rec.thread.start()
        svc.publish("take", rec.info)
        return dict(rec.info)

    @svc.handler("status")
    def status(req):
        return info_of(req["take"])

    @svc.handler("stop")
    def stop(req):
        with lock:
            rec = live.get(req["take"])
        if rec is not None:
            rec.stop.set()
            if rec.thread is not None:
                rec.thread.join(timeout=30.0)
        return info_of(req["take"])

    def finished(take: str):
        from shared.io import load_clip

        info = info_of(take)
        if info["state"] == "recording":
            raise Conflict(f"take {take!r} is still being recorded", take=take)
        if info["state"] != "done":
            raise Conflict(f"take {take!r} failed: {info.get('error', info['ended'])}", take=take)
        return load_clip(root / f"{take}.bvh")

    @svc.cost("clip")
    def clip_cost(req):
        """A finished take read whole: its BVH parsed, ~1.5 KB per frame (bench.budget)."""
        return 1536 * info_of(req["take"])["frames"]

    @svc.cost("segment")
    def segment_cost(req):
        """The take read whole and its features at the segmentation's rate, ~3.6 KB per frame
        (bench.budget: the features and alignments of a 100,000-frame take held 346 MB)."""
        from shared.capture.segment import FPS

        info = info_of(req["take"])
        return 1536 * info["frames"] + 3686 * FPS * info["seconds"]

    @svc.handler("clip")
    def clip(req):
        return {"take": req["take"], "clip": clip_to_wire(finished(req["take"]))}

    @svc.handler("segment")
    def segment_take(req):
        from shared.capture.segment import segment

        target = clip_from_wire(req["target"])
        with lock:
            known = cut.get(req["take"])
            ground = grounds.get(req["take"])
        recorded_with, named = (ground[1], ground[2]) if ground is not None and _same(ground[0], target) else ([], (None, None))
        if req.get("space") and (req["space"] != named[0] or req.get("label") is not None):
            named = (req["space"], req.get("label"))  # (the same space without a label: the label recorded with)
        if (known is not None and not req["background"] and known[1] == req["expected"] and _same(known[0], target)
                and known[4] == named and info_of(req["take"])["state"] == "done"):
            take, result = known[2], known[3]  # found while recording: the same take, target, count, cohort and space
        else:
            take = finished(req["take"])
            background = [clip_from_wire(c) for c in req["background"]] or recorded_with
            result = segment(take, target, expected=req["expected"], background=background,
                             space=space_of(named[0]), label=named[1])
        return {"take": req["take"], "verdict": result.verdict, "expected": req["expected"], "notes": result.notes,
                "repetitions": [{k: v for k, v in r.to_dict().items() if v is not None} for r in result.repetitions],
                "clips": [clip_to_wire(c) for c in result.cut(take)]}

    @svc.handler("list")
    def list_takes(req):
        names = sorted({p.stem for p in root.glob("*.json")} | set(live))
        out, damaged = [], []
        for n in names:
            try:
                out.append(info_of(n))
            except NotFound:  # deleted while listed
                continue
            except DamagedFile as e:  # listed apart, with what is wrong with its file
                damaged.append(e.listed())
        return {"takes": out, "damaged": damaged}

    return svc
