"""A proto-symbol space as one ``.npz`` file (arrays plus a JSON header, no pickle), written
atomically, and journal entries that add proto-symbols to a saved file without rewriting it.
Functions of a space: :class:`shared.pss.space.ProtoSymbolSpace`'s ``save``, ``save_added``
and ``load`` call them."""

from __future__ import annotations

import dataclasses
import json
import uuid
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from shared.errors import BadInput, NotFound
from shared.io.atomic import atomic_write
from shared.io.npz import NOT_AN_ARCHIVE, Stacked, npz_problem, savez_stacked
from shared.pss.features import MotionFeatures
from shared.pss.hmm import LeftToRightHMM
from shared.pss.mds import Embedding
from shared.pss.symbol import GEOMETRY_GROUPS, READABLE_FORMATS, ProtoSymbol, SpaceParams

if TYPE_CHECKING:  # annotations only: the space imports this module
    from shared.pss.space import ProtoSymbolSpace


def file_contents(space: ProtoSymbolSpace, first: int = 0) -> tuple[dict, dict]:
    """The header and arrays of a space file holding proto-symbols ``first:`` (0: the whole
    space; more: a journal entry of the ones :meth:`added` put after them)."""
    syms = space.symbols[first:]
    header = {
        "format": space.format,  # a format-1 space saved again keeps its content, hence its format
        "name": space.name,
        "params": space.params.to_dict(),
        "features": space.features.to_json(),
        "symbols": [{"name": s.name, "label": s.label, "clips": s.clips, "n_frames": s.n_frames,
                     "performers": s.performers,
                     "n_iter": s.hmm.n_iter, "converged": s.hmm.converged, "log_likelihood": s.hmm.log_likelihood,
                     "hmm_frames": s.hmm.n_frames} for s in syms],
        "embedding": {"stress": space.embedding.stress, "stress1": space.embedding.stress1,
                      "n_iter": space.embedding.n_iter, "converged": space.embedding.converged},
        # recognition's decision (shared/pss/recognition.py), kept so that a loaded space
        # recognises without refitting it (and without importing scipy.optimize)
        "calibration": dataclasses.asdict(space.calibration),
        "novelty": None if space.novelty_model is None else space.novelty_model.header(),
        "discriminant": None if space.discriminant is None else space.discriminant.header(),
        "first": first,
    }
    arrays = {
        "means": Stacked([s.hmm.means for s in syms]),  # written symbol by symbol, never stacked
        "covars": Stacked([s.hmm.covars for s in syms]),
        "stay": np.stack([s.hmm.stay for s in syms]),
        "distances": space.distances[first:],  # the rows of these proto-symbols, every column
        "points": space.points[first:],
    }
    if space.recognition_weights is not None:
        arrays["recognition_weights"] = space.recognition_weights
    if space.recognition_groups != GEOMETRY_GROUPS and space.params.covariance_type == "diag":
        # kept so that adding a clip to a loaded space extends it by one row instead of
        # recomputing N^2 / 2 distances (14 s for 3,000 proto-symbols)
        arrays["recognition_matrix"] = space.recognition_matrix[first:]
    for model in (space.novelty_model, space.discriminant):
        if model is not None:
            arrays.update(model.arrays())
    return header, arrays

def save(space: ProtoSymbolSpace, path) -> Path:
    """Write the space to one ``.npz`` file, atomically (temporary file, then rename). The
    file gets a new ``generation``: journal entries of an older file of the same path are
    not this space's (:meth:`save_added`)."""
    path = Path(path)
    header, arrays = file_contents(space)
    space.generation, space.base_count = uuid.uuid4().hex, len(space.symbols)
    header["generation"] = space.generation
    arrays["header"] = np.array(json.dumps(header))
    atomic_write(path, lambda f: savez_stacked(f, arrays))
    return path

def save_added(space: ProtoSymbolSpace, path, first: int) -> Path:
    """Write only proto-symbols ``first:`` (those :meth:`added` put after the ones of the
    saved space it came from), their distance rows, points and the refitted decision: a
    journal entry that :meth:`load` applies to the saved file (``O(N)`` bytes per clip
    instead of the whole space)."""
    if space.generation is None:
        raise BadInput("a journal entry needs the space it adds to saved first")
    if not 0 < first < len(space.symbols):
        raise BadInput(f"nothing added after proto-symbol {first} of {len(space.symbols)}")
    header, arrays = file_contents(space, first)
    for k in ("params", "features"):  # the saved file's: the same for every entry
        header.pop(k)
    header["generation"] = space.generation
    arrays["header"] = np.array(json.dumps(header))
    atomic_write(Path(path), lambda f: savez_stacked(f, arrays))
    return Path(path)

#: what a space file (or a journal entry) may unpack to, checked before numpy reads it: about six
#: times a space of 3,000 proto-symbols (its N x N distances twice and 0.18 GB of HMMs)
MAX_SPACE_BYTES = 2 * 1024 ** 3


def read(path) -> tuple[dict, dict, dict]:
    """A space file's header, arrays and the open set's fitted tests' arrays."""
    if Path(path).is_file():
        why = npz_problem(Path(path), {}, MAX_SPACE_BYTES)
        if why == NOT_AN_ARCHIVE:
            raise BadInput(f"{path}: not a space file (not an NPZ archive; `offline build` writes one)")
        if why is not None:
            raise BadInput(f"{path}: not a readable space file ({why})")
    try:
        with np.load(path, allow_pickle=False) as z:  # each z[k] is a new array of its own (not copied again)
            header = json.loads(str(z["header"]))
            arrays = {k: z[k] for k in ("means", "covars", "stay", "distances", "points")}
            for k in ("recognition_weights", "recognition_matrix"):
                arrays[k] = z[k] if k in z.files else None
            # the open set's fitted tests, each its header entry and arrays named after it
            tests = {key: {k: z[k] for k in z.files if k.startswith(f"{key}_")}
                     for key in ("novelty", "discriminant")}
    except FileNotFoundError:
        raise NotFound(f"no space file {path}") from None
    except (OSError, KeyError, ValueError) as e:
        raise BadInput(f"{path}: not a readable space file ({e})") from None
    if header.get("format") not in READABLE_FORMATS:
        raise BadInput(f"{path}: unknown space format {header.get('format')!r} (this mirrorcoach reads "
                       f"{', '.join(READABLE_FORMATS)}; a newer mirrorcoach may have written it)")
    return header, arrays, tests

def symbols_of(header: dict, arrays: dict, params: SpaceParams) -> list[ProtoSymbol]:
    out = []
    for i, s in enumerate(header["symbols"]):
        hmm = LeftToRightHMM(arrays["means"][i], arrays["covars"][i], arrays["stay"][i], params.covariance_type,
                             n_iter=s["n_iter"], converged=s["converged"], log_likelihood=s["log_likelihood"],
                             n_frames=s["hmm_frames"])
        out.append(ProtoSymbol(s["name"], s["label"], hmm, s["clips"], s["n_frames"], s.get("performers", [])))
    return out

def load(cls: type[ProtoSymbolSpace], path, added=()) -> ProtoSymbolSpace:
    """A saved space, with the journal entries ``added`` (:meth:`save_added`, in the order
    written) applied: an entry of another generation of the file (left by a rewrite) is
    skipped; one that does not follow the proto-symbols so far is refused."""
    path = Path(path)
    header, arrays, tests = read(path)
    try:
        return _space_of(cls, path, header, arrays, tests, added)
    except (KeyError, IndexError, TypeError, ValueError, AttributeError) as e:  # a damaged header: no traceback
        raise BadInput(f"{path}: not a readable space file (its header: {type(e).__name__}: {e}); build the space "
                       "again from its clips") from None


def _space_of(cls: type[ProtoSymbolSpace], path: Path, header: dict, arrays: dict, tests: dict,
              added) -> ProtoSymbolSpace:
    """:func:`load`'s space from the file's contents (:func:`read`)."""
    params = SpaceParams(**header["params"])
    features = MotionFeatures.from_json(header["features"])
    symbols = symbols_of(header, arrays, params)
    e = header["embedding"]
    emb = Embedding(arrays["points"], e["stress"], e["stress1"], e["n_iter"], e["converged"])
    distances, rec_matrix = arrays["distances"], arrays["recognition_matrix"]
    base_count = len(symbols)
    for entry in added:
        eh, ea, et = read(entry)
        if eh.get("generation") != header.get("generation") or eh.get("generation") is None:
            continue
        n, m = len(symbols), len(eh["symbols"])
        if eh.get("first") != n or ea["distances"].shape != (m, n + m):
            raise BadInput(f"{entry}: a journal entry after proto-symbol {eh.get('first')} ({m} of them), the space "
                           f"has {n}: the journal is damaged; build the space again")
        symbols += symbols_of(eh, ea, params)
        distances = _grown(distances, ea["distances"])
        if rec_matrix is not None and ea["recognition_matrix"] is not None:
            rec_matrix = _grown(rec_matrix, ea["recognition_matrix"])
        e = eh["embedding"]
        emb = Embedding(np.vstack([emb.points, ea["points"]]), e["stress"], e["stress1"], e["n_iter"], e["converged"])
        header = {**header, **{k: eh.get(k) for k in ("calibration", "novelty", "discriminant")}}
        tests = et
    space = cls(params, features, symbols, distances, emb, name=header["name"])
    space.format = header["format"]
    space.generation, space.base_count = header.get("generation"), base_count
    if space.recognition_groups != GEOMETRY_GROUPS and params.covariance_type == "diag":
        # a file written before the channel weights recognises as it did when written (its
        # calibration was fitted on unweighted distances); rebuilding it gives the weights
        weights = arrays["recognition_weights"]
        space._recognition_weights = weights if weights is not None else np.ones(len(space.features.group_indices(
            space.recognition_groups)))
        if rec_matrix is not None and rec_matrix.shape == space.distances.shape:
            space._recognition_matrix = rec_matrix
    restore_decision(space, header, tests, path)
    return space

def restore_decision(space: ProtoSymbolSpace, header: dict, tests: dict, path) -> None:
    """Recognition's calibration, novelty model and discriminant ratio as the file holds them."""
    params = space.params
    if header.get("calibration"):
        from shared.pss.recognition import Calibration

        try:
            cal = Calibration(**header["calibration"])
            if cal.class_scales is not None and len(cal.class_scales) != len(cal.classes):
                raise ValueError(f"{len(cal.class_scales)} class spreads for {len(cal.classes)} classes")
        except (TypeError, ValueError) as e:
            raise BadInput(f"{path}: its recognition calibration is unreadable ({e}); build the space again "
                           "from its clips") from None
        space._calibration = cal
    from shared.pss.recognition import DiscriminantRatio, NoveltyModel, hmm_features

    n = len(space.features.group_indices(space.recognition_groups))
    n_features = len(hmm_features(np.zeros((params.n_states, n)), np.ones((params.n_states, n))))
    for key, kind, what in (("novelty", NoveltyModel, "novelty model"),
                            ("discriminant", DiscriminantRatio, "discriminant ratio")):
        if header.get(key) and tests[key]:
            try:
                model = kind.from_file(header[key], tests[key])
                if len(model.mean) != n_features:  # it would fail on the first recognition
                    raise ValueError(f"it reads {len(model.mean)} features, the space's motions have {n_features}")
                setattr(space, f"_{key}", model)
            except (KeyError, TypeError, ValueError) as e:
                raise BadInput(f"{path}: its {what} is unreadable ({type(e).__name__}: {e}); build the space "
                               "again from its clips") from None
        elif header.get("calibration"):  # written before this test: its open set as written (without
            setattr(space, f"_{key}", False)  # the model; the ratio on eq. 2.4 distances)


def _grown(matrix: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """A symmetric ``n x n`` matrix extended by ``m`` rows of ``n + m`` columns (and their mirror)."""
    n, m = len(matrix), len(rows)
    out = np.empty((n + m, n + m))
    out[:n, :n] = matrix
    out[n:, :] = rows
    out[:n, n:] = rows[:, :n].T
    return out
