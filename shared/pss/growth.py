"""A space grown by clips without rebuilding it: new proto-symbols, their eq. 2.4 distances to
the ones already there (N per clip, not N^2), their points placed among the fixed points as eq.
2.6 places a recognised motion, and the caches carried over, extended by the new rows.
:meth:`shared.pss.space.ProtoSymbolSpace.added` calls :func:`added`."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from shared.errors import BadInput
from shared.motion.clip import Clip
from shared.pss.distance import ModelBank, bank_parameters, distances_to
from shared.pss.mds import Embedding, pair_squares, place_point
from shared.pss.rows import appended, padded
from shared.pss.symbol import GEOMETRY_GROUPS, ProtoSymbol, performer

if TYPE_CHECKING:  # annotations only: the space imports this module
    from shared.pss.space import ProtoSymbolSpace


def added(old: ProtoSymbolSpace, clips: list[Clip]) -> ProtoSymbolSpace:
    """A new space with one proto-symbol per clip added **without rebuilding the rest**: the
    new HMMs, their eq. 2.4 distances to the proto-symbols already there (N per clip, not
    N^2), their points placed among the fixed points as eq. 2.6 places a recognised motion
    (the others keep theirs), the recognition distances extended by the same rows (with the
    space's channel weights as they are). Recognition's calibration, discriminant ratio and
    novelty model are fitted again, lazily, from the extended distances and HMMs.
    :meth:`~shared.pss.space.ProtoSymbolSpace.rebuilt` re-embeds every point instead (eq. 2.5 from scratch)."""
    if not clips:
        raise BadInput("no clips to add")
    names = {s.name for s in old.symbols}
    symbols = list(old.symbols)
    for c in clips:
        c = c.resample(old.params.fps)
        if c.name in names:
            raise BadInput(f"space {old.name!r} already has a proto-symbol named {c.name!r}")
        symbols.append(ProtoSymbol(c.name, c.label or c.name, old.abstract([c]), [c.name], [c.n_frames],
                                   [performer(c)]))
        names.add(c.name)
    n, new = len(old.symbols), symbols[len(old.symbols):]
    geo = old.features.group_indices(GEOMETRY_GROUPS)
    f = padded(old.distances, len(symbols))
    bank = old.bank_on(GEOMETRY_GROUPS)
    for k, sym in enumerate(new):
        row = np.r_[bank.distances(sym.hmm.marginal(geo)),
                    [distances_to(sym.hmm.marginal(geo), [o.hmm.marginal(geo)])[0] for o in new[:k]]]
        f[n + k, :n + k] = f[:n + k, n + k] = row
    points = np.empty((len(symbols), old.points.shape[1]))
    points[:n] = old.points
    # the stress and sum f_ij^2 of the pairs (i < j) grow by the new points' pairs alone: the
    # other points do not move (the old sum f_ij^2 is the old stress over its stress-1 squared)
    stress = float(old.embedding.stress)
    total = stress / old.embedding.stress1 ** 2 if old.embedding.stress1 > 0 else pair_squares(old.distances)
    for k in range(len(new)):
        row = f[n + k, :n + k]
        points[n + k], _ = place_point(points[:n + k], row)
        stress += float(np.sum((row - np.linalg.norm(points[:n + k] - points[n + k], axis=1)) ** 2))
        total += float(np.sum(row * row))
    emb = Embedding(points, stress, float(np.sqrt(stress / max(total, 1e-300))),
                    old.embedding.n_iter, old.embedding.converged)
    space = type(old)(old.params, old.features, symbols, f, emb, name=old.name)
    space.format, space.generation = old.format, old.generation  # a journal entry names its saved base
    space.base_count = old.base_count
    if old.recognition_groups != GEOMETRY_GROUPS:
        space._recognition_weights = old.recognition_weights
        old.recognition_bank()  # built here once, then carried (and extended) to every space added to this one
    carry_caches(old, space, n)
    if old.recognition_groups != GEOMETRY_GROUPS:
        w = old.recognition_weights
        rec = space.recognition_models()
        m = padded(old.recognition_matrix, len(symbols))
        known = old.recognition_bank()
        for k in range(len(new)):
            row = np.r_[known.distances(rec[n + k]),
                        ModelBank(rec[n:n + k], w).distances(rec[n + k]) if k else []]
            m[n + k, :n + k] = m[:n + k, n + k] = row
        space._recognition_matrix = m
    return space

def carry_caches(old: ProtoSymbolSpace, space: ProtoSymbolSpace, n: int) -> None:
    """Give ``space`` (``old`` with proto-symbols added after the first ``n``) the old
    space's per-group models, banks and symbol features, extended by the new proto-symbols
    only: recomputing them for every proto-symbol cost an add to a 3,000-clip space 0.7 s."""
    new = space.symbols[n:]
    for key, value in old._group_models.items():
        if not isinstance(value, ModelBank) or key[0] == "weighted bank":
            continue
        idx = old.features.group_indices(key[1:])
        more = [m.hmm if len(idx) == old.features.n_features else m.hmm.marginal(idx) for m in new]
        if key[0] == "recognition":
            more = [space.as_recognised(m) for m in more]
        space._group_models[key] = value.extended(more)
    rg = tuple(old.recognition_groups)
    stack = space._group_models.get(("recognition",) + rg)
    weighted = old._group_models.get(("weighted bank",) + rg)
    if stack is not None and weighted is not None:  # the same arrays as the stack, as in this space
        space._group_models[("weighted bank",) + rg] = stack.weighted(weighted.weights)
    feats = old._group_models.get(("symbol features",))
    if feats is not None and stack is not None:
        from shared.pss.recognition import hmm_features

        space._group_models[("symbol features",)] = appended(feats, hmm_features(*bank_parameters(stack, n)))
