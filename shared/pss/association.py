"""Association, eq. 2.8 (``M_whole = F_gen(F_recog(M_partial))``): the whole pattern of a
partial one, missing sensor channels or missing frames, and how far the motion lies beyond what
the space learnt (``reach``). A part of :class:`shared.pss.space.ProtoSymbolSpace` (a mixin: it
uses the space's models, distances, placement and generation)."""

from __future__ import annotations

import numpy as np

from shared.clip import Clip
from shared.errors import BadInput
from shared.pss.distance import distance_matrix, distances_to
from shared.pss.hmm import fit_hmm
from shared.pss.symbol import Association
from shared.pss.synthesis import generate


class Associating:
    """Eq. 2.8 on a proto-symbol space (mixed into :class:`~shared.pss.space.ProtoSymbolSpace`)."""

    def _marginal_scale(self, group: str) -> float:
        """Factor mapping eq. 2.4 distances on one channel group to the space's (geometry)
        distances, fitted by least squares on the space's own pairs."""
        if group not in self._partial_scale:
            part = distance_matrix(self.models_on((group,)))
            iu = np.triu_indices(len(self.symbols), 1)
            num = float(np.sum(part[iu] * self.distances[iu]))
            den = float(np.sum(part[iu] ** 2))
            self._partial_scale[group] = num / den if den > 0 else 1.0
        return self._partial_scale[group]

    def associate(self, clip: Clip, missing: str = "sensor", *, method: str = "expected", seed: int = 0,
                  weighting: str | None = None) -> Association:
        """Eq. 2.8: the whole pattern from a partial one.

        ``missing="sensor"``: the clip has the motion channels only; recognition uses the
        motion part of every proto-symbol (distances rescaled to the full scale), the whole
        pattern is generated from the point, and the sensor channels are also estimated on
        the clip's own frames (their expectation under the synthesised HMM's state posteriors).

        ``missing="frames"``: the clip is the start of a motion; how far it reaches is read
        from the state posterior of its last frame under the best-fitting proto-symbol, and
        the clip is compared with that many first states of every proto-symbol.

        ``weighting``: how the point becomes proto-symbol weights: ``"affine"`` (exact, may
        extrapolate) or ``"inverse_distance"`` (convex: the estimate stays among the known
        patterns, which is steadier for motions outside the space's hull; ch. 3 uses it).
        ``None``: inverse-distance for missing sensor channels, affine for missing frames.
        Chosen on HDM05's bd and bk splits (arm torques from motion, eq. 3.9 error against
        the training mean's: inverse-distance 31 / 24 % below it, affine 17 / 10 %) and
        reported on dg (32 % below, affine 9 %).
        """
        if weighting is None:
            weighting = "inverse_distance" if missing == "sensor" else "affine"
        if missing == "sensor":
            return self._associate_channels(clip, method, seed, weighting)
        if missing == "frames":
            return self._associate_frames(clip, method, seed, weighting)
        raise BadInput(f"missing must be 'sensor' or 'frames', got {missing!r}")

    def _associate_channels(self, clip, method, seed, weighting="affine") -> Association:
        if not self.features.sensor_channels:
            raise BadInput(f"space {self.name!r} has no sensor channels to associate")
        # the motion is recognised on the recognition group (positions where the space has them:
        # eq. 3.9 error 26.6 % against 33.8 % on the angle channels, HDM05 arm torques, 13 states)
        group = "position" if self.features.has_position else "motion"
        seqs = self._sequences(clip, ("motion", "position") if group == "position" else ("motion",))
        gidx = self.features.feature_indices(group)
        p = self.params
        hmm = fit_hmm([x[:, gidx] for x in seqs], p.n_states, covariance_type=p.covariance_type,
                      var_floor=p.var_floor, backend=p.backend, n_iter=p.n_iter)
        f = self.bank_on((group,)).distances(hmm) * self._marginal_scale(group)
        rec = self._place(hmm, f)
        reach = self._reach((group,), float(np.min(f)) / self._marginal_scale(group))
        c = self.weights(rec.point, method=weighting)
        model = self.synthesize(c)
        whole = self.features.decode(generate(model, method=method, seed=seed), p.fps, name=f"{clip.name}-whole")
        # the missing channels on the observed frames: E[s_t] = sum_i gamma_t(i) mu_i^S, the state
        # posteriors read on the recognition group (positions: no Euler branch enters)
        gamma = model.marginal(gidx).posteriors(seqs[0][:, gidx])
        sidx = self.features.feature_indices("sensor")
        est = gamma @ model.means[:, sidx]
        sens = est * self.features.sensor_scale + self.features.sensor_mean
        obs = clip.resample(p.fps)
        aligned = Clip(np.hstack([obs.select(self.features.motion_channels), sens]),
                       self.features.motion_channels + self.features.sensor_channels, p.fps, obs.skeleton,
                       {"motion": list(self.features.motion_channels), "sensor": list(self.features.sensor_channels)},
                       name=f"{clip.name}-associated", label=rec.label)
        return Association(rec, c, whole, aligned, reach=reach)

    def _associate_frames(self, clip, method, seed, weighting="affine") -> Association:
        p = self.params
        groups = ("motion", "sensor") if set(self.features.sensor_channels) <= set(clip.channels) and self.features.sensor_channels else ("motion",)
        seq = self._sequences(clip, groups, min_frames=2)[0]  # the start of a motion: k <= frames states
        models = self.models_on(groups)
        best_ll, best_prog = -np.inf, None
        for m in models:
            ll = m.log_likelihood_of([seq], end_in_last=False)
            if ll > best_ll:
                best_ll, best_prog = ll, m.progress(seq)
        k = int(np.argmax(best_prog)) + 1
        k = int(np.clip(k, 1, min(p.n_states, len(seq))))
        hmm = fit_hmm([seq], k, covariance_type=p.covariance_type, var_floor=p.var_floor, backend=p.backend, n_iter=p.n_iter)
        f = distances_to(hmm, [m.prefix(k) for m in models]) * (p.n_states / k)
        if groups == ("motion",) and self.features.sensor_channels:
            f = f * self._marginal_scale("motion")
        rec = self._place(hmm, f)
        scale = self._marginal_scale("motion") if groups == ("motion",) and self.features.sensor_channels else 1.0
        reach = self._reach(groups, float(np.min(f)) / scale)
        c = self.weights(rec.point, method=weighting)
        whole = self.features.decode(generate(self.synthesize(c), method=method, seed=seed), p.fps, name=f"{clip.name}-whole")
        return Association(rec, c, whole, None, progress=k / p.n_states, reach=reach)

    def _reach(self, groups: tuple, nearest: float) -> float:
        """``nearest`` (an eq. 2.4 distance on ``groups``) over the 95th percentile of the
        proto-symbols' nearest-neighbour distances on the same groups, each to the proto-symbols
        of other performers when the space has several (a new motion is a new performer's: its
        own performer's takes are not in the space); cached per groups."""
        key = ("nearest neighbours",) + tuple(groups)
        if key not in self._group_models:
            d = distance_matrix(self.models_on(groups)) if len(self.symbols) > 1 else np.zeros((1, 1))
            np.fill_diagonal(d, np.inf)
            perf = np.array(self.performers)
            if len(set(perf)) > 1:
                d = np.where(perf[:, None] == perf[None, :], np.inf, d)
            nn = d.min(axis=1)
            self._group_models[key] = float(np.quantile(nn[np.isfinite(nn)], 0.95)) if np.isfinite(nn).any() else 0.0
        ref = self._group_models[key]
        return float(nearest / ref) if ref > 0 else float("inf")
