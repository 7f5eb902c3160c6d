"""Association, eq. 2.8 (``M_whole = F_gen(F_recog(M_partial))``): the whole pattern of a
partial one, missing sensor channels or missing frames, and how far the motion lies beyond what
the space learnt (``reach``). Functions of a space (:class:`shared.pss.space.ProtoSymbolSpace`; its ``associate``
calls :func:`associate`): they use its models, distances, placement and generation."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from shared.errors import BadInput
from shared.motion.clip import Clip
from shared.pss.distance import distance_matrix, distances_to
from shared.pss.hmm import fit_hmm, fit_hmm_once
from shared.pss.symbol import Association, at_space_rate
from shared.pss.synthesis import distance_weights, generate

if TYPE_CHECKING:  # annotations only: the space imports this module
    from shared.pss.space import ProtoSymbolSpace


def marginal_scale(space: ProtoSymbolSpace, group: str) -> float:
    """Factor mapping eq. 2.4 distances on one channel group to the space's (geometry)
    distances, fitted by least squares on the space's own pairs."""
    if group not in space._partial_scale:
        part = distance_matrix(space.models_on((group,)))
        iu = np.triu_indices(len(space.symbols), 1)
        num = float(np.sum(part[iu] * space.distances[iu]))
        den = float(np.sum(part[iu] ** 2))
        space._partial_scale[group] = num / den if den > 0 else 1.0
    return space._partial_scale[group]

#: the weighting of an association with missing sensor channels when none is asked (:func:`associate`)
SENSOR_WEIGHTING = "distance"


def associate(space: ProtoSymbolSpace, clip: Clip, missing: str = "sensor", *, method: str = "expected", seed: int = 0,
              weighting: str | None = None, whole: bool = True) -> Association:
    """Eq. 2.8: the whole pattern from a partial one.

    ``missing="sensor"``: the clip has the motion channels only; recognition uses the
    motion part of every proto-symbol (distances rescaled to the full scale), the whole
    pattern is generated from the point, and the sensor channels are also estimated on
    the clip's own frames (their expectation under the synthesised HMM's state posteriors).

    ``missing="frames"``: the clip is the start of a motion; how far it reaches is read
    from the state posterior of its last frame under the best-fitting proto-symbol, and
    the clip is compared with that many first states of every proto-symbol.

    ``weighting``: how the motion becomes proto-symbol weights: ``"distance"`` (convex, from
    its eq. 2.4 distances to every proto-symbol, the way recognition weighs them:
    :func:`shared.pss.synthesis.distance_weights`), or from its point in the space,
    ``"affine"`` (exact, may extrapolate) or ``"inverse_distance"`` (convex; ch. 3's estimator
    asks for it). ``None``: distance for missing sensor channels, affine for missing frames.
    Missing sensor channels, HDM05 arm torques from motion, eq. 3.9 error below the training
    mean's, test performers bd / bk / dg each against a space of the other two: distance 33 /
    41 / 33 %, the point's inverse distance (the default before) 29 / 24 / 32 %; the power
    chosen on the inner splits (one training performer's space against the other's clips;
    docs/pss.md, "Association across performers").

    ``whole=False`` (missing sensor channels only): the whole pattern is not generated
    (``Association.whole`` is ``None``): a caller that reads only the sensor channels on the
    clip's own frames (the estimator, ch. 3) saves the generation, a third of the association.
    """
    if weighting is None:
        weighting = SENSOR_WEIGHTING if missing == "sensor" else "affine"
    if missing == "sensor":
        return associate_channels(space, clip, method, seed, weighting, whole)
    if missing == "frames":
        return associate_frames(space, clip, method, seed, weighting)
    raise BadInput(f"missing must be 'sensor' or 'frames', got {missing!r}")

def associate_channels(space: ProtoSymbolSpace, clip, method, seed, weighting="affine", whole=True) -> Association:
    if not space.features.sensor_channels:
        raise BadInput(f"space {space.name!r} has no sensor channels to associate")
    # the motion is recognised on the recognition group (positions where the space has them:
    # eq. 3.9 error 26.6 % against 33.8 % on the angle channels, HDM05 arm torques, 13 states)
    group = "position" if space.features.has_position else "motion"
    seqs = space._sequences(clip, ("motion", "position") if group == "position" else ("motion",))
    gidx = space.features.feature_indices(group)
    p = space.params
    # (trained once per process: the estimator's spaces associate the same motions over and over)
    hmm = fit_hmm_once([x[:, gidx] for x in seqs], p.n_states, covariance_type=p.covariance_type,
                       var_floor=p.var_floor, backend=p.backend, n_iter=p.n_iter)
    f = space.bank_on((group,)).distances(hmm) * marginal_scale(space, group)
    rec = space._place(hmm, f)
    reach = reach_of(space, (group,), float(np.min(f)) / marginal_scale(space, group))
    c = _weights(space, rec, f, weighting)
    model = space.synthesize(c)
    generated = space.features.decode(generate(model, method=method, seed=seed), p.fps,
                                      name=f"{clip.name}-whole") if whole else None
    # the missing channels on the observed frames: E[s_t] = sum_i gamma_t(i) mu_i^S, the state
    # posteriors read on the recognition group (positions: no Euler branch enters)
    gamma = model.marginal(gidx).posteriors(seqs[0][:, gidx])
    sidx = space.features.feature_indices("sensor")
    est = gamma @ model.means[:, sidx]
    sens = est * space.features.sensor_scale + space.features.sensor_mean
    obs = clip.resample(p.fps)
    aligned = Clip(np.hstack([obs.select(space.features.motion_channels), sens]),
                   space.features.motion_channels + space.features.sensor_channels, p.fps, obs.skeleton,
                   {"motion": list(space.features.motion_channels), "sensor": list(space.features.sensor_channels)},
                   name=f"{clip.name}-associated", label=rec.label)
    return Association(rec, c, generated, aligned, reach=reach)

def associate_frames(space: ProtoSymbolSpace, clip, method, seed, weighting="affine") -> Association:
    p = space.params
    groups = ("motion", "sensor") if set(space.features.sensor_channels) <= set(clip.channels) and space.features.sensor_channels else ("motion",)
    seq = space._sequences(clip, groups, min_frames=2)[0]  # the start of a motion: k <= frames states
    models = space.models_on(groups)
    best_ll, best_prog = -np.inf, None
    for m in models:
        ll = m.log_likelihood_of([seq], end_in_last=False)
        if ll > best_ll:
            best_ll, best_prog = ll, m.progress(seq)
    assert best_prog is not None  # (one model at least)
    k = int(np.argmax(best_prog)) + 1
    k = int(np.clip(k, 1, min(p.n_states, len(seq))))
    hmm = fit_hmm([seq], k, covariance_type=p.covariance_type, var_floor=p.var_floor, backend=p.backend, n_iter=p.n_iter)
    f = distances_to(hmm, [m.prefix(k) for m in models]) * (p.n_states / k)
    if groups == ("motion",) and space.features.sensor_channels:
        f = f * marginal_scale(space, "motion")
    rec = space._place(hmm, f)
    scale = marginal_scale(space, "motion") if groups == ("motion",) and space.features.sensor_channels else 1.0
    reach = reach_of(space, groups, float(np.min(f)) / scale)
    c = _weights(space, rec, f, weighting)
    whole = space.features.decode(generate(space.synthesize(c), method=method, seed=seed), p.fps, name=f"{clip.name}-whole")
    return Association(rec, c, whole, None, progress=k / p.n_states, reach=reach)

def _weights(space: ProtoSymbolSpace, rec, f: np.ndarray, weighting: str) -> np.ndarray:
    """Eq. 4.2's proto-symbol weights of an association: from the motion's eq. 2.4 distances
    ``f`` (``"distance"``) or from its point ``rec.point`` (``"affine"``, ``"inverse_distance"``)."""
    return distance_weights(f) if weighting == "distance" else space.weights(rec.point, method=weighting)


def reach_of(space: ProtoSymbolSpace, groups: tuple, nearest: float) -> float:
    """``nearest`` (an eq. 2.4 distance on ``groups``) over the 95th percentile of the
    proto-symbols' nearest-neighbour distances on the same groups, each to the proto-symbols
    of other performers when the space has several (a new motion is a new performer's: its
    own performer's takes are not in the space); cached per groups."""
    key = ("nearest neighbours",) + tuple(groups)
    if key not in space._group_models:
        d = distance_matrix(space.models_on(groups)) if len(space.symbols) > 1 else np.zeros((1, 1))
        np.fill_diagonal(d, np.inf)
        perf = np.array(space.performers)
        if len(set(perf)) > 1:
            d = np.where(perf[:, None] == perf[None, :], np.inf, d)
        nn = d.min(axis=1)
        space._group_models[key] = float(np.quantile(nn[np.isfinite(nn)], 0.95)) if np.isfinite(nn).any() else 0.0
    ref = space._group_models[key]
    return float(nearest / ref) if ref > 0 else float("inf")


def recognize_by_positions(space: ProtoSymbolSpace, clips: list, top: int = 5):
    """``F_recog`` of clips on another studio's skeleton (:mod:`shared.pss.foreign`): an HMM of
    their position group alone (no joint angle of theirs compares with the space's), labelled by
    the recognition distances as any clip is, placed by the position distances rescaled to the
    space's (:func:`marginal_scale`)."""
    p = space.params
    if space.recognition_groups != ("position",):
        raise BadInput(f"space {space.name!r} has no position features to read a clip on another skeleton with")
    seqs = []
    for c in clips:
        if not np.all(np.isfinite(c.data)):
            raise BadInput(f"clip {c.name!r} contains NaN or Inf")
        seqs.append(space.features.positions(at_space_rate(c, p.fps, p.n_states, "HMM states, a frame each")))
    hmm = fit_hmm(seqs, p.n_states, covariance_type=p.covariance_type, var_floor=p.var_floor, backend=p.backend,
                  n_iter=p.n_iter)
    hr = space.as_recognised(hmm)
    f = space.bank_on(("position",)).distances(hmm) * marginal_scale(space, "position")
    rec = space._place(hmm, f, top, space.recognition_bank().distances(hr), hr)
    rec.another_skeleton = True
    return rec
