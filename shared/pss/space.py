"""The Proto-symbol Space: ``P = F_build(D)`` (eq. 2.5), ``x = F_recog(M)`` (eq. 2.6),
``M = F_gen(x)`` (eq. 2.7) and association ``M_whole = F_gen(F_recog(M_partial))`` (eq. 2.8).

A space holds a database ``D`` of clips abstracted into proto-symbols (left-to-right HMMs,
:mod:`shared.pss.hmm`), their pairwise eq. 2.4 distances and their points from metric MDS
(:mod:`shared.pss.mds`). Every HMM of a space has the same number of states; by default that
number comes from the shortest repetition (85 % of its frames, between 2 and 15) so that no
state is left without frames. All clips are resampled to the space's frame rate (30 fps by
default) and encoded by :class:`~shared.pss.features.MotionFeatures`.

Each HMM models the channel groups of :class:`~shared.pss.features.MotionFeatures` together:
``motion`` (invertible angles and root terms) and ``sensor`` (torques...) give the space its
geometry (the eq. 2.4 distances MDS places, generation, emphasis), ``position`` (joints in the
heading frame) decides recognition's label (:mod:`shared.pss.recognition`).

A space is one ``.npz`` file (arrays plus a JSON header, no pickle), written atomically;
loading it gives identical points, distances and generations. Every random step is seeded.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from shared.errors import BadInput, NotFound
from shared.motion.clip import Clip
from shared.pss import association, foreign, growth, spacefile
from shared.pss.distance import ModelBank, bank_parameters, distance_matrix
from shared.pss.features import MotionFeatures
from shared.pss.hmm import LeftToRightHMM, fit_hmm
from shared.pss.mds import Embedding, place_point, smacof
from shared.pss.rows import spare
from shared.pss.symbol import (  # the space's parts, named here too (its public API, __all__)
    FORMAT,
    GEOMETRY_GROUPS,
    MAX_STATES,
    ONE_EXAMPLE_POSE_FLOOR,
    READABLE_FORMATS,
    RECOGNITION_VAR_CEILING,
    STYLE_POSE_FLOOR,
    Association,
    ProtoSymbol,
    Recognition,
    SpaceParams,
    at_space_rate,
    default_n_states,
    default_pose_floor,
    performer,
)
from shared.pss.synthesis import combine, generate, point_weights

if TYPE_CHECKING:  # annotations only: recognition's decision is imported where it is fitted
    from shared.pss.recognition import Calibration

__all__ = ["ProtoSymbolSpace", "ProtoSymbol", "SpaceParams", "Recognition", "Association", "default_n_states",
           "performer", "FORMAT", "READABLE_FORMATS", "GEOMETRY_GROUPS", "MAX_STATES", "RECOGNITION_VAR_CEILING",
           "STYLE_POSE_FLOOR", "ONE_EXAMPLE_POSE_FLOOR", "default_pose_floor"]


class _AtRate(Sequence):
    """A sequence of clips seen at ``fps`` (each resampled when taken, none kept)."""

    def __init__(self, clips: Sequence[Clip], fps: float):
        self.clips, self.fps = clips, fps

    def __len__(self) -> int:
        return len(self.clips)

    def __getitem__(self, i):  # an index (a Clip); Sequence also allows slices, which nothing here takes
        c = self.clips[i]
        return c if c.fps == self.fps else c.resample(self.fps)


class ProtoSymbolSpace:
    """A named space ``P`` built from a database ``D`` (see module docstring)."""

    def __init__(self, params: SpaceParams, features: MotionFeatures, symbols: list[ProtoSymbol],
                 distances: np.ndarray, embedding: Embedding, name: str = "space"):
        self.params = params
        self.features = features
        self.symbols = symbols
        self.distances = distances
        self.embedding = embedding
        self.name = name
        self.format = FORMAT
        self._partial_scale: dict[str, float] = {}
        self._group_models: dict[tuple, Any] = {}  # per channel groups: models, banks, symbol features
        self._calibration: Calibration | None = None
        self._novelty: Any = None  # NoveltyModel, fitted on first use; False: a file written before it
        self._discriminant: Any = None  # DiscriminantRatio, likewise; False: written before it (eq. 2.4 ratio)
        self._recognition_matrix: np.ndarray | None = None
        self._recognition_weights: np.ndarray | None = None  # computed on first use, or read from the file
        self.generation: str | None = None  # the saved file's (save), which journal entries name
        self.base_count = 0  # proto-symbols in that file (the rest are in journal entries)

    # ------------------------------------------------------------------ build
    @classmethod
    def build(cls, clips: Sequence[Clip], *, n_states: int | None = None, dim: int = 3, fps: float = 30.0,
              covariance_type: str = "diag", var_floor: float = 0.01, backend: str = "banded",
              group_by: str = "clip", sensor: bool = True, name: str = "space", progress=None,
              pose_floor: float | None = None, open_set: bool = True) -> ProtoSymbolSpace:
        """``P = F_build(D)`` (eq. 2.5).

        Parameters
        ----------
        clips : sequence of Clip
            The database ``D``; every clip needs a ``label`` (its motion class). A list, or a
            lazy sequence that reads a clip when it is indexed (:class:`shared.io.LazyClips`):
            each clip is then taken twice (the features' statistics, then its HMM) and never
            held, so a space of thousands of clips builds in the memory of its HMMs.
        group_by : {"clip", "label"}
            One proto-symbol per clip, or one per label trained on all its repetitions.
        progress : callable(done, total), optional
            Called after every HMM is trained.
        pose_floor : float, optional
            Recognition's variance floor on the position group's pose outputs (diagonal spaces):
            for a space that must recognise motions done in styles it does not hold
            (:data:`STYLE_POSE_FLOOR`; none by default here; ``offline build`` and ``space build``
            give a space of one clip per motion :func:`default_pose_floor`).
        open_set : bool
            False: for association and generation only, "none of these" by the distance rule alone
            (the novelty model and discriminant ratio not fitted: most of saving a small space).
        """
        if not len(clips):
            raise BadInput("a space needs at least one clip")
        if group_by not in ("clip", "label"):
            raise BadInput(f"group_by must be 'clip' or 'label', got {group_by!r}")
        if dim < 1:
            raise BadInput("dimension must be at least 1")
        if isinstance(clips, list):  # held by the caller anyway: each at the space's rate once
            clips = [c if c.fps == fps else c.resample(fps) for c in clips]
        else:
            clips = _AtRate(clips, fps)
        seen: list[tuple[str, str | None, int, str]] = []  # name, label, frames, performer of every clip
        features = MotionFeatures.for_clips(clips, sensor=sensor, on_clip=lambda c: seen.append(
            (c.name, c.label, c.n_frames, performer(c))))
        groups: dict[str, list[int]] = {}
        for i, (clip_name, label, _, _) in enumerate(seen):
            key = (label or clip_name) if group_by == "label" else clip_name
            if key in groups and group_by == "clip":
                raise BadInput(f"two clips are named {key!r}; clip names must be unique in a space")
            groups.setdefault(key, []).append(i)
        short = min(range(len(seen)), key=lambda i: seen[i][2])
        shortest = seen[short][2]
        if n_states is None:
            n_states = default_n_states(shortest)
        if shortest < n_states:
            raise BadInput(f"clip {seen[short][0]!r} has {shortest} frames at {fps:g} fps, fewer than {n_states} HMM states",
                           frames=shortest, states=n_states)
        params = SpaceParams(recognition_var_ceiling=RECOGNITION_VAR_CEILING if covariance_type == "diag" else None,
                             n_states=n_states, fps=fps, dim=dim, covariance_type=covariance_type,
                             var_floor=var_floor, backend=backend, group_by=group_by).with_pose_floor(pose_floor)
        symbols = []
        for i, (key, members) in enumerate(groups.items()):
            seqs = [features.encode(clips[k]) for k in members]
            hmm = fit_hmm(seqs, n_states, covariance_type=covariance_type, var_floor=var_floor, backend=backend,
                          n_iter=params.n_iter)
            del seqs
            symbols.append(ProtoSymbol(key, seen[members[0]][1] or key, hmm, [seen[k][0] for k in members],
                                       [seen[k][2] for k in members], [seen[k][3] for k in members]))
            if progress:
                progress(i + 1, len(groups))
        space = cls.from_symbols(params, features, symbols, name=name)
        if not open_set:
            space._novelty = space._discriminant = False
        return space

    @classmethod
    def from_symbols(cls, params: SpaceParams, features: MotionFeatures, symbols: list[ProtoSymbol],
                     name: str = "space") -> ProtoSymbolSpace:
        geo = features.group_indices(GEOMETRY_GROUPS)
        bank = ModelBank.of([s.hmm for s in symbols], None if len(geo) == features.n_features else geo)
        f = distance_matrix(bank)
        emb = smacof(f, params.dim)
        space = cls(params, features, symbols, f, emb, name=name)
        # kept: recognition and adding a clip measure eq. 2.4 against it (at 3,000 proto-symbols
        # stacking it again took an add 0.6 s, most of it the first touch of new memory)
        space._group_models[("bank",) + GEOMETRY_GROUPS] = bank
        return space

    def added(self, clips: list[Clip]) -> ProtoSymbolSpace:
        """A new space with one proto-symbol per clip added **without rebuilding the rest**: the
        new HMMs, their eq. 2.4 distances to the proto-symbols already there (N per clip, not
        N^2), their points placed among the fixed points as eq. 2.6 places a recognised motion
        (the others keep theirs), the recognition distances extended by the same rows (with the
        space's channel weights as they are). Recognition's calibration, discriminant ratio and
        novelty model are fitted again, lazily, from the extended distances and HMMs.
        :meth:`rebuilt` re-embeds every point instead (eq. 2.5 from scratch)."""
        return growth.added(self, clips)

    def rebuilt(self, add: list[Clip] | None = None, remove: list[str] | None = None,
                as_one: str | None = None) -> ProtoSymbolSpace:
        """A new space from a modified database (ch. 3 rebuilds every conversation set).

        ``as_one``: add the clips as the repetitions of one proto-symbol of that name (a
        learner's attempt of 5 repetitions, ch. 4) instead of one proto-symbol per clip."""
        removed = set(remove or [])
        unknown = removed - {s.name for s in self.symbols}
        if unknown:
            raise NotFound(f"no proto-symbol named {sorted(unknown)[0]!r} in space {self.name!r}")
        symbols = [s for s in self.symbols if s.name not in removed]
        names = {s.name for s in symbols}
        if as_one is not None:
            if as_one in names:
                raise BadInput(f"space {self.name!r} already has a proto-symbol named {as_one!r}")
            reps = [c.resample(self.params.fps) for c in add or []]
            if not reps:
                raise BadInput("no clips to add")
            symbols.append(ProtoSymbol(as_one, reps[0].label or as_one, self.abstract(reps), [c.name for c in reps],
                                       [c.n_frames for c in reps], [performer(c) for c in reps]))
            add = []
        for c in add or []:
            c = c.resample(self.params.fps)
            if c.name in names:
                raise BadInput(f"space {self.name!r} already has a proto-symbol named {c.name!r}")
            hmm = self.abstract([c])
            symbols.append(ProtoSymbol(c.name, c.label or c.name, hmm, [c.name], [c.n_frames], [performer(c)]))
            names.add(c.name)
        if not symbols:
            raise BadInput("a space needs at least one proto-symbol")
        return ProtoSymbolSpace.from_symbols(self.params, self.features, symbols, name=self.name)

    # ------------------------------------------------------------------ access
    @property
    def points(self) -> np.ndarray:
        return self.embedding.points

    @property
    def labels(self) -> list[str]:
        return [s.label for s in self.symbols]

    @property
    def names(self) -> list[str]:
        return [s.name for s in self.symbols]

    @property
    def models(self) -> list[LeftToRightHMM]:
        return [s.hmm for s in self.symbols]

    def symbol(self, name_or_label: str) -> int:
        for i, s in enumerate(self.symbols):
            if s.name == name_or_label:
                return i
        hits = [i for i, s in enumerate(self.symbols) if s.label == name_or_label]
        if len(hits) == 1:
            return hits[0]
        if hits:
            raise BadInput(f"label {name_or_label!r} names {len(hits)} proto-symbols; use one of their names, e.g. {self.symbols[hits[0]].name!r}")
        raise NotFound(f"no proto-symbol {name_or_label!r} in space {self.name!r}")

    # ------------------------------------------------------------------ recognition
    def _sequences(self, clip_or_clips, groups=("motion", "position", "sensor"), min_frames: int | None = None) -> list[np.ndarray]:
        """Feature frames of the clips at the space's rate (:func:`at_space_rate`), ``min_frames`` each (default: states)."""
        clips = [clip_or_clips] if isinstance(clip_or_clips, Clip) else list(clip_or_clips)
        if not clips:
            raise BadInput("nothing to recognise")
        seqs = []
        for c in clips:
            if not np.all(np.isfinite(c.data)):
                raise BadInput(f"clip {c.name!r} contains NaN or Inf")
            need = self.params.n_states if min_frames is None else min_frames
            c = at_space_rate(c, self.params.fps, need, "HMM states, a frame each" if min_frames is None else "frames")
            seqs.append(self.features.encode(c, groups))
        return seqs

    def abstract(self, clip_or_clips, groups=("motion", "position", "sensor"),
                 n_states: int | None = None, likelihood: bool = True) -> LeftToRightHMM:
        """Abstract one or several repetitions into an HMM with the space's settings
        (``likelihood``: :func:`shared.pss.hmm.fit_hmm`'s)."""
        p = self.params
        if "sensor" in groups and self.features.sensor_channels:
            clips = [clip_or_clips] if isinstance(clip_or_clips, Clip) else list(clip_or_clips)
            if any(not set(self.features.sensor_channels) <= set(c.channels) for c in clips):
                raise BadInput("the clip lacks this space's sensor channels; use associate() to estimate them")
        seqs = self._sequences(clip_or_clips, groups)
        return fit_hmm(seqs, n_states or p.n_states, covariance_type=p.covariance_type, var_floor=p.var_floor,
                       backend=p.backend, n_iter=p.n_iter, likelihood=likelihood)

    def models_on(self, groups) -> list[LeftToRightHMM]:
        """The proto-symbols seen on some channel groups (views of :meth:`bank_on`'s arrays)."""
        idx = self.features.group_indices(tuple(groups))
        return self.models if len(idx) == self.features.n_features else self.bank_on(groups).models

    def recognition_models(self) -> list[LeftToRightHMM]:
        """The proto-symbols on the recognition groups as recognition compares them (their
        variances capped, :data:`RECOGNITION_VAR_CEILING`; views of one cached stack)."""
        return self._recognition_stack().models

    def _recognition_stack(self) -> ModelBank:
        key = ("recognition",) + tuple(self.recognition_groups)
        if key not in self._group_models:
            idx = self.features.group_indices(self.recognition_groups)
            self._group_models[key] = ModelBank.of(self.models, None if len(idx) == self.features.n_features else idx,
                                                   self._ceiling(), self._recognition_floor())
        return self._group_models[key]

    def _ceiling(self) -> float | None:
        """Recognition's variance ceiling (None: none, older files and full covariances)."""
        return self.params.recognition_var_ceiling if self.params.covariance_type == "diag" else None

    def _recognition_floor(self) -> np.ndarray | None:
        """Recognition's variance floor of every output of the recognition groups (None: none; cached)."""
        key = ("recognition floor",)
        if key not in self._group_models:
            self._group_models[key] = (self.params.recognition_floors(self.features, self.recognition_groups)
                                       if self.params.covariance_type == "diag" else None)
        return self._group_models[key]

    def with_pose_floor(self, pose_floor: float | None) -> ProtoSymbolSpace:
        """This space recognising with ``pose_floor``: its proto-symbols, distances and points as they are."""
        return ProtoSymbolSpace(self.params.with_pose_floor(pose_floor), self.features, self.symbols, self.distances,
                                self.embedding, name=self.name)

    def as_recognised(self, hmm: LeftToRightHMM) -> LeftToRightHMM:
        """``hmm`` (on the recognition groups) as recognition compares it: its variances floored
        (the space's pose floor, if any: :data:`STYLE_POSE_FLOOR`) and capped
        (:data:`RECOGNITION_VAR_CEILING`)."""
        ceiling, floor = self._ceiling(), self._recognition_floor()
        if (ceiling is None and floor is None) or hmm.covariance_type != "diag":
            return hmm
        var = hmm.covars if floor is None else np.maximum(hmm.covars, floor)
        var = var if ceiling is None else np.minimum(var, ceiling)
        return LeftToRightHMM(hmm.means, var, hmm.stay, hmm.covariance_type)

    def bank_on(self, groups) -> ModelBank:
        """The proto-symbols on some channel groups stacked for fast eq. 2.4 (cached)."""
        key = ("bank",) + tuple(groups)
        if key not in self._group_models:
            idx = self.features.group_indices(tuple(groups))
            self._group_models[key] = ModelBank.of(self.models, None if len(idx) == self.features.n_features else idx)
        return self._group_models[key]

    @property
    def recognition_groups(self) -> tuple[str, ...]:
        """The channel groups recognition's label is decided on: ``position`` where the space
        has it, else the geometry groups (format-1 spaces, robots without a skeleton)."""
        return ("position",) if self.features.has_position else GEOMETRY_GROUPS

    @property
    def performers(self) -> list[str]:
        """Each proto-symbol's performer (the skeleton of its first clip; "" when it had none)."""
        return [s.performers[0] if s.performers else "" for s in self.symbols]

    @property
    def recognition_weights(self) -> np.ndarray | None:
        """Channel weights of the recognition distance on the position group
        (:func:`shared.pss.recognition.channel_weights`); ``None`` where recognition uses the
        geometry groups (format 1, no skeleton: eq. 2.4 unweighted, as those spaces always did)."""
        if self.recognition_groups == GEOMETRY_GROUPS or self.params.covariance_type != "diag":
            return None  # full covariances: eq. 2.4 unweighted (the weights are per channel)
        if self._recognition_weights is None:
            from shared.pss.recognition import channel_weights

            stack = self._recognition_stack()
            self._recognition_weights = channel_weights(stack.means, stack.vars, self.labels, self.performers)
        return self._recognition_weights

    def recognition_bank(self) -> ModelBank:
        """The proto-symbols on the recognition groups, stacked with the channel weights (cached)."""
        rg = self.recognition_groups
        key = ("weighted bank",) + rg
        if key not in self._group_models:
            self._group_models[key] = self._recognition_stack().weighted(self.recognition_weights)
        return self._group_models[key]

    @property
    def recognition_matrix(self) -> np.ndarray:
        """Weighted eq. 2.4 between the proto-symbols on the recognition groups."""
        if self._recognition_matrix is None:
            self._recognition_matrix = (self.distances if self.recognition_groups == GEOMETRY_GROUPS
                                        else distance_matrix(self.recognition_bank()))
        return self._recognition_matrix

    @property
    def calibration(self):
        """Confidence temperature and open-set threshold (:mod:`shared.pss.recognition`)."""
        if self._calibration is None:
            from shared.pss.recognition import calibrate

            perf = self.performers
            self._calibration = calibrate(self.recognition_matrix, self.labels, perf if all(perf) else [])
        return self._calibration

    @property
    def novelty_model(self):
        """The open set's discriminative step (:class:`shared.pss.recognition.NoveltyModel`), fitted
        on the proto-symbols' recognition-group HMMs; ``None`` for a file written before it (its
        open set stays the distance rule it was written with) or a space of one class."""
        if self._novelty is None:
            from shared.pss.recognition import NoveltyModel

            perf = self.performers
            self._novelty = NoveltyModel.fit(self._symbol_features(), self.labels, perf if all(perf) else None) or False
        return self._novelty or None

    @property
    def discriminant(self):
        """The open set's ratio test in a discriminant space
        (:class:`shared.pss.recognition.DiscriminantRatio`), fitted on the same features as the
        novelty model; ``None`` for a file written before it (its ratio test stays on eq. 2.4
        distances) or a space of one class."""
        if self._discriminant is None:
            from shared.pss.recognition import DiscriminantRatio

            perf = self.performers
            self._discriminant = DiscriminantRatio.fit(self._symbol_features(), self.labels,
                                                       perf if all(perf) else None) or False
        return self._discriminant or None

    def _symbol_features(self) -> np.ndarray:
        """The proto-symbols' recognition-group HMMs as vectors (:func:`shared.pss.recognition.hmm_features`),
        computed once for the novelty model and the discriminant ratio."""
        key = ("symbol features",)
        if key not in self._group_models:
            from shared.pss.recognition import hmm_features

            feats = hmm_features(*bank_parameters(self._recognition_stack()))
            self._group_models[key] = spare(feats.shape)  # spare rows: an added clip's row goes in place
            self._group_models[key][:] = feats
        return self._group_models[key]

    def recognize(self, clip_or_clips, top: int = 5) -> Recognition:
        """``x = F_recog(M)`` (eq. 2.6): abstract the new clip (or the repetitions of one trial,
        into one HMM together) into an HMM, measure eq. 2.4 to every proto-symbol, decide its label
        (nearest proto-symbol on the recognition group, calibrated confidence, "none of these" when
        it is farther than the space's known motions; :mod:`shared.pss.recognition`) and place it
        without moving the space's points. Clips on another studio's skeleton are read by their
        joints' positions alone (:mod:`shared.pss.foreign`). Returns a :class:`Recognition`:
        ``label`` (``None``: "none of these"), ``confidence``, ``novelty``, the ``point`` in the
        space and its ``stress``, the ``top`` nearest proto-symbols and the decision's tests."""
        t0 = time.perf_counter()
        clips = [clip_or_clips] if isinstance(clip_or_clips, Clip) else list(clip_or_clips)
        if clips and all(foreign.is_foreign(c.skeleton, self.features.skeleton) for c in clips):
            rec = association.recognize_by_positions(self, clips, top)  # another studio's skeleton
            rec.seconds = time.perf_counter() - t0
            return rec
        hmm = self.abstract(clip_or_clips, likelihood=False)  # compared by eq. 2.4 only, never scored
        geo = self.features.group_indices(GEOMETRY_GROUPS)
        f = self.bank_on(GEOMETRY_GROUPS).distances(hmm.marginal(geo))
        rg = self.recognition_groups
        hr = self.as_recognised(hmm.marginal(self.features.group_indices(rg)))
        fr = f if rg == GEOMETRY_GROUPS else self.recognition_bank().distances(hr)
        rec = self._place(hmm, f, top, fr, hr)
        rec.seconds = time.perf_counter() - t0
        return rec

    def _place(self, hmm, f, top=5, fr=None, hr=None) -> Recognition:
        """Eq. 2.6 placement by the geometry distances ``f``. With recognition distances ``fr``
        the label is decided (:mod:`shared.pss.recognition`); without (association, eq. 2.8,
        on partial channels) it is the nearest proto-symbol's by ``f``, with no confidence."""
        from shared.pss.recognition import decide

        x, stress = place_point(self.points, f)
        order = np.argsort(f if fr is None else fr)
        dist = f if fr is None else fr
        nearest = [(self.symbols[i].name, self.symbols[i].label, float(dist[i])) for i in order[:top]]
        in_space = int(np.argmin(np.linalg.norm(self.points - x, axis=1)))
        if fr is None:
            lab = self.symbols[order[0]].label
            return Recognition(x, f, nearest, lab, self.symbols[in_space].label, stress, hmm, nearest_label=lab,
                               confidence=float("nan"))
        from shared.pss.recognition import hmm_features

        model, disc = self.novelty_model, self.discriminant
        d = decide(fr, self.labels, self.calibration, model,
                   None if (model is None and disc is None) or hr is None else hmm_features(hr.means, hr.covars), disc)
        return Recognition(x, f, nearest, d.label, self.symbols[in_space].label, stress, hmm,
                           nearest_label=d.nearest_label, confidence=d.confidence, novelty=d.novelty,
                           recognition_distances=fr, decision=d)

    # ------------------------------------------------------------------ generation
    def weights(self, point, method: str = "affine") -> np.ndarray:
        return point_weights(self.points, point, method=method)

    def mix_weights(self, mix: dict[str, float]) -> np.ndarray:
        """Weights from ``{proto-symbol name or label: weight}`` (must sum to 1)."""
        c = np.zeros(len(self.symbols))
        for key, w in mix.items():
            c[self.symbol(key)] += float(w)
        if abs(c.sum() - 1.0) > 1e-6:
            raise BadInput(f"mix weights must sum to 1 (they sum to {c.sum():.6g})")
        return c

    def synthesize(self, weights) -> LeftToRightHMM:
        """The HMM of a weighted combination of proto-symbols (eq. 4.2, time-domain durations)."""
        return combine(self.models, weights, var_floor=self.params.var_floor * 1e-2)

    def point_of(self, weights) -> np.ndarray:
        return np.asarray(weights, float) @ self.points

    def generate(self, point=None, *, weights=None, method: str = "expected", n_frames: int | None = None,
                 seed: int = 0, name: str = "generated") -> Clip:
        """``M = F_gen(x)`` (eq. 2.7 / 4.1) from a point or from explicit proto-symbol weights.

        Parameters
        ----------
        point : array (dim,), optional
            A point of the space; its proto-symbol weights come from :meth:`weights`.
        weights : array (n_proto_symbols,), optional
            The weights of eq. 4.2 themselves (summing to 1; they may be negative: emphasis).
            Exactly one of ``point`` and ``weights``.
        method : {"expected", "monte_carlo"}
            The expected output trajectory (deterministic) or the mean of sampled paths.
        n_frames : int, optional
            Frames of the result (default: the synthesised HMM's expected duration).
        seed : int
            The seed of the Monte Carlo paths.

        Returns
        -------
        Clip
            The motion decoded at the space's frame rate, on the space's skeleton.
        """
        if (point is None) == (weights is None):
            raise BadInput("give either a point or weights")
        c = self.weights(point) if weights is None else np.asarray(weights, float)
        if c.shape != (len(self.symbols),):
            raise BadInput(f"need {len(self.symbols)} weights, got {c.size}")
        model = self.synthesize(c)
        x = generate(model, n_frames, method=method, seed=seed)
        return self.features.decode(x, self.params.fps, name=name)

    def emphatic_weights(self, target: str, attempt: str, alpha: float) -> np.ndarray:
        """Weights of the emphatic point ``x_s = x_t + alpha (x_t - x_p)`` (eq. 4.3).

        Parameters
        ----------
        target, attempt : str
            Names (or labels) of the target's and the learner's attempt's proto-symbols.
        alpha : float
            The emphasis: 0 shows the target, larger pushes it further from the attempt.

        Returns
        -------
        array (n_proto_symbols,)
            ``1 + alpha`` on the target, ``-alpha`` on the attempt, 0 elsewhere (for :meth:`generate`).
        """
        c = np.zeros(len(self.symbols))
        c[self.symbol(target)] += 1.0 + alpha
        c[self.symbol(attempt)] -= alpha
        return c

    # ------------------------------------------------------------------ association and the file
    def associate(self, clip: Clip, missing: str = "sensor", *, method: str = "expected", seed: int = 0,
                  weighting: str | None = None, whole: bool = True) -> Association:
        """Eq. 2.8: the whole pattern from a partial one (missing sensor channels or missing
        frames); :func:`shared.pss.association.associate` says how."""
        return association.associate(self, clip, missing, method=method, seed=seed, weighting=weighting, whole=whole)

    def save(self, path) -> Path:
        """Write the space to one ``.npz`` file, atomically (:func:`shared.pss.spacefile.save`)."""
        return spacefile.save(self, path)

    def save_added(self, path, first: int) -> Path:
        """Write proto-symbols ``first:`` as a journal entry of the saved file
        (:func:`shared.pss.spacefile.save_added`)."""
        return spacefile.save_added(self, path, first)

    @classmethod
    def load(cls, path, added=()) -> ProtoSymbolSpace:
        """A saved space with its journal entries ``added`` applied (:func:`shared.pss.spacefile.load`)."""
        return spacefile.load(cls, path, added)

    # ------------------------------------------------------------------ summary
    def info(self) -> dict:
        return {
            "name": self.name,
            "n_proto_symbols": len(self.symbols),
            "labels": sorted(set(self.labels)),
            "params": self.params.to_dict(),
            "n_features": self.features.n_features,
            "sensor_channels": list(self.features.sensor_channels),
            "stress": self.embedding.stress,
            "stress1": self.embedding.stress1,
            "mds_converged": self.embedding.converged,
            "hmm_converged": sum(s.hmm.converged for s in self.symbols),
            "format": self.format,
            "recognition": ("nearest proto-symbol on joint positions in the heading frame" if self.features.has_position
                            else "nearest proto-symbol on the angle channels (format 1: rebuild the space from its "
                                 "clips for position-based recognition)" if self.format != FORMAT
                            else "nearest proto-symbol on the motion channels (no skeleton)"),
            **self._open_set_info(),
        }

    def _open_set_info(self) -> dict:
        from shared.pss.recognition import can_reject, open_set_text

        old_ratio, no_model = self._discriminant is False, self._novelty is False  # as saved, before a fit
        rejects = can_reject(self.calibration, self.discriminant, self.novelty_model)
        return {"open_set": open_set_text(self.calibration, len(set(self.labels)), old_ratio, no_model, rejects),
                "rejects": rejects}
