"""The PSS model service: owns the named Proto-symbol Spaces (contract: ``schemas/pss.py``).

Thin by design: every handler validates nothing itself (the runtime did), converts the wire
clips, calls ``shared.pss`` and shapes the reply. State lives in a :class:`SpaceStore` under
``$MIRRORCOACH_HOME/data/pss``.
"""

from __future__ import annotations

import hashlib
import threading
import weakref
from collections import OrderedDict

import numpy as np

from schemas import pss as contract
from schemas.common import clip_from_wire, clip_to_wire
from shared.bus.codec import pack
from shared.bus.config import Settings
from shared.bus.runtime import Service
from shared.errors import BadInput, Conflict, NotFound
from shared.pss.space import ProtoSymbolSpace
from shared.pss.store import SpaceStore


def space_info(name: str, space: ProtoSymbolSpace) -> dict:
    info = space.info()
    info.pop("name", None)
    info["space"] = name
    info["params"] = {k: v for k, v in info["params"].items() if v is not None}  # absent: a space saved before it
    info["proto_symbols"] = [{"name": s.name, "label": s.label} for s in space.symbols]
    info["points"] = np.asarray(space.points, dtype=np.float64)
    info["mds_converged"] = bool(info["mds_converged"])
    info["hmm_converged"] = int(info["hmm_converged"])
    info["stress"], info["stress1"] = float(info["stress"]), float(info["stress1"])
    return info


def _warm() -> None:
    """Load the compiled kernels of training, distances and the embedding once at start (0.4 s of
    loading cached machine code), so that the first request does not pay for them: a person's
    first trial waits on the coach, which waits on this."""
    from shared.pss.distance import distance_matrix
    from shared.pss.hmm import fit_hmm
    from shared.pss.mds import smacof

    r = np.random.default_rng(0)
    models = [fit_hmm([r.random((12, 3))], 3, n_iter=2) for _ in range(3)]
    smacof(distance_matrix(models), 2, max_iter=2)


#: a generation without ``frames`` takes the expected durations: a few seconds of motion
DEFAULT_FRAMES_ESTIMATE = 2000
#: bytes per feature and frame (at the space's rate) of reading clips as features and fitting
#: their HMMs (bench.budget: an attempt of 20 x 5,000 frames added to a space peaked at 27)
FEATURE_BYTES = 32
#: features per channel when the space is not built yet (HDM05's skeleton: 237 from 62)
FEATURES_PER_CHANNEL = 4


def feature_cost(clips: list[dict], fps: float, n_features: int | None = None) -> float:
    """Working memory (bytes) of reading the wire ``clips`` as a space's features at ``fps`` and
    fitting HMMs on them: frames at the space's rate x features x ``FEATURE_BYTES``."""
    return sum(FEATURE_BYTES * (n_features or FEATURES_PER_CHANNEL * c["data"].shape[1])
               * len(c["data"]) * fps / c["fps"] for c in clips)


def make_service(settings: Settings | None = None) -> Service:
    settings = settings or Settings()
    # recognition's calibration uses scikit-learn, whose OpenMP pool loads with it: loaded here,
    # before the first build, so that the runner's thread limit and its log line cover it
    import sklearn.covariance  # noqa: F401
    import sklearn.linear_model  # noqa: F401

    _warm()
    # deployed, every instance starts as a standby: it recovers the store when it starts to lead
    store = SpaceStore(settings.data_dir("pss"), recover=settings.identity is None)
    svc = Service(contract.SERVICE, contract.ENDPOINTS, contract.EVENTS, settings=settings, workers=settings.workers)

    def changed(name, change, space=None):
        svc.publish("space", {"space": name, "change": change,
                              "n_proto_symbols": 0 if space is None else len(space.symbols),
                              **({} if space is None else {"info": space_info(name, space)})})

    def write(name, operation, make):
        with store.writing(name, operation):  # a kill (not an exception) leaves the marker
            space = make()
            store.commit(name, space)
        return space

    @svc.cost("build")
    def build_cost(req):
        return feature_cost(req["clips"], req["fps"])

    @svc.cost("add")
    @svc.cost("recognize")
    def clips_cost(req):  # (a recognition of files is estimated by its payload)
        space = store.get(req["space"])
        return feature_cost(req.get("clips") or [], space.params.fps, space.features.n_features)

    # name -> (the build request's digest, the space it made): a build with replace of the same clips
    # and settings as the space it would replace is that space (a build is deterministic); the
    # estimator rebuilds its spaces whenever a conversation resumes, a third of its builds
    built: OrderedDict[str, tuple[str, weakref.ref]] = OrderedDict()
    built_lock = threading.Lock()

    def last_build(name: str):
        """The content digest of the last build of ``name`` and the space it made (``None`` when
        that space is gone: deleted or forgotten)."""
        with built_lock:
            last = built.get(name)
        return (None, None) if last is None else (last[0], last[1]())

    def unchanged(name: str, digest: str):
        """The stored space when the last build of ``name`` was this request and nothing has
        changed the space since (add, delete, another build, a promotion: another object)."""
        last, made = last_build(name)
        if made is None or last != digest:  # (never loaded from its file just to compare)
            return None
        try:
            current = store.get(name)
        except NotFound:
            return None
        return current if made is current else None

    def content_digest(req) -> str:
        """What a build request makes, whatever the space's name: the estimator's spaces of the
        self's own torques are the same clips under the name of every estimate."""
        return hashlib.sha256(pack({k: v for k, v in req.items() if k not in ("replace", "space")})).hexdigest()

    # (what the space is, the association request without the space's name) -> the reply: an
    # association is deterministic (its seed is in the request), so a space built from the same
    # clips answers the same; bounded, the oldest forgotten
    associations: OrderedDict[tuple[str, str], dict] = OrderedDict()

    @svc.handler("build")
    def build(req):
        name = req["space"]
        if store.exists(name) and not req["replace"]:
            raise Conflict(f"space {name!r} exists; delete it first or build with replace", space=name)
        digest = content_digest(req)
        same = unchanged(name, digest)
        if same is not None:
            return space_info(name, same)
        clips = [clip_from_wire(c) for c in req["clips"]]
        space = write(name, "build", lambda: ProtoSymbolSpace.build(
            clips, n_states=req["n_states"], dim=req["dim"], fps=req["fps"],
            covariance_type=req["covariance_type"], group_by=req["group_by"], name=name, pose_floor=req.get("pose_floor"),
            open_set=req["open_set"]))
        with built_lock:
            built[name] = (digest, weakref.ref(space))
            built.move_to_end(name)
            while len(built) > 1024:  # bounded: the oldest builds are forgotten (and made again if asked)
                built.popitem(last=False)
        changed(name, "built", space)
        return space_info(name, space)

    @svc.handler("add")
    def add(req):
        name = req["space"]
        old = store.get(name)
        clips = [clip_from_wire(c, old.features.skeleton) for c in req["clips"]]
        if not req["rebuild"] and req["as_one"] is not None:
            raise BadInput("as_one needs rebuild: a proto-symbol of several repetitions is placed by a rebuild")
        if req["rebuild"]:
            space = write(name, "add", lambda: old.rebuilt(add=clips, as_one=req["as_one"]))
        else:  # placed among the fixed points: a journal entry of the new proto-symbols, not the whole file
            with store.writing(name, "add"):
                space = old.added(clips)
                store.append(name, space, len(old.symbols))
        changed(name, "added", space)
        return space_info(name, space)

    @svc.handler("recognize")
    def recognize(req):
        space = store.get(req["space"])
        if req["files"] is not None:
            from shared.bus.wirefiles import READING_OPTIONS, read_wire_files

            clips = read_wire_files(req["files"], {k: req[k] for k in READING_OPTIONS})
        else:
            clips = [clip_from_wire(c, space.features.skeleton) for c in req["clips"]]
        rec = space.recognize(clips[0] if len(clips) == 1 else clips, top=req["top"])
        decided = {"label": rec.label} if rec.label is not None else {}
        if rec.label is None and rec.decision is not None:
            from shared.pss.recognition import rejected_by

            decided["rejected_by"] = rejected_by(rec.decision)
        return {"space": req["space"], **decided, "known": rec.label is not None, "nearest_label": rec.nearest_label,
                "confidence": float(rec.confidence), "novelty": float(rec.novelty), "label_in_space": rec.label_in_space,
                "point": np.asarray(rec.point, float), "stress": float(rec.stress), "seconds": float(rec.seconds),
                "nearest": [{"name": n, "label": lab, "distance": float(d)} for n, lab, d in rec.nearest],
                **({"another_skeleton": True} if rec.another_skeleton else {})}

    @svc.cost("generate")
    def generate_cost(req):
        """Working memory of a generation: 8 bytes x 3 per feature and frame (bench.budget: the
        library peaks at 2.1 x the feature frames; the reply's clip and its packing add the rest)."""
        frames = req["frames"] or DEFAULT_FRAMES_ESTIMATE
        return 8 * 3 * frames * store.get(req["space"]).features.n_features

    @svc.handler("generate")
    def generate(req):
        space = store.get(req["space"])
        if req["point"] is not None:
            point = req["point"]
            if point.shape != (space.params.dim,):
                raise BadInput(f"generate: the point has {point.size} coordinates, space {req['space']!r} has {space.params.dim}",
                               field="point")
            weights = space.weights(point)
        else:
            weights = space.mix_weights(req["mix"])
            point = space.point_of(weights)
        clip = space.generate(weights=weights, method=req["method"], n_frames=req["frames"], seed=req["seed"],
                              name=req["name"])
        return {"space": req["space"], "clip": clip_to_wire(clip), "weights": np.asarray(weights, float),
                "point": np.asarray(point, float)}

    @svc.handler("associate")
    def associate(req):
        space = store.get(req["space"])
        digest, made = last_build(req["space"])  # a space added to, loaded or promoted since: not kept
        key = None if made is not space else (digest, hashlib.sha256(pack({k: v for k, v in req.items() if k != "space"})).hexdigest())
        if key is not None:
            with built_lock:
                kept = associations.get(key)
            if kept is not None:
                return {**kept, "space": req["space"]}
        clip = clip_from_wire(req["clip"], space.features.skeleton)
        a = space.associate(clip, req["missing"], method=req["method"], seed=req["seed"], weighting=req["weighting"],
                            whole=req["whole"])
        out = {"space": req["space"], "label": a.recognition.label, "point": np.asarray(a.recognition.point, float)}
        if a.whole is not None:
            out["whole"] = clip_to_wire(a.whole)
        if a.aligned is not None:
            out["aligned"] = clip_to_wire(a.aligned, with_skeleton=False)
        if a.progress is not None:
            out["progress"] = float(a.progress)
        if np.isfinite(a.reach):
            out["reach"], out["extrapolating"] = float(a.reach), a.extrapolating
        if key is not None:
            with built_lock:
                associations[key] = out
                while len(associations) > 2048:
                    associations.popitem(last=False)
        return out

    @svc.handler("distance")
    def distance(req):
        space = store.get(req["space"])
        i, j = space.symbol(req["a"]), space.symbol(req["b"])
        return {"space": req["space"], "a": space.symbols[i].name, "b": space.symbols[j].name,
                "distance": float(space.distances[i, j])}

    @svc.handler("info")
    def info(req):
        return space_info(req["space"], store.get(req["space"]))

    @svc.handler("list")
    def list_spaces(req):
        rows, damaged = [], []
        for name in store.names():
            try:
                sp = store.get(name)
            except NotFound:  # deleted while listed
                continue
            except BadInput as e:  # its file cannot be read back: listed apart, the others still are
                damaged.append({"kind": "space", "name": name, "message": e.message})
                continue
            rows.append({"space": name, "n_proto_symbols": len(sp.symbols), "labels": sorted(set(sp.labels)),
                         "dim": sp.params.dim, "stress1": float(sp.embedding.stress1)})
        return {"spaces": rows, "interrupted": store.interrupted(), "damaged": damaged}

    @svc.handler("delete")
    def delete(req):
        try:
            store.delete(req["space"])
        except NotFound:
            if not req["missing_ok"]:
                raise
            return {"space": req["space"], "deleted": False}
        changed(req["space"], "deleted")
        return {"space": req["space"], "deleted": True}

    svc.store = store
    svc.on_promote.append(store.take_over)
    return svc
