"""A rerun recording read back with rerun's own reader (``rerun.chunk.RrdReader``): what was
logged, entity by entity (the tests read recordings this way; pictures of a recording come from
the real viewer, :mod:`shared.observe.viewer`)."""

from __future__ import annotations

from collections import defaultdict


def read(path) -> dict[str, list[dict]]:
    """Entity path -> rows ``{timeline or component: value}`` in logging order."""
    from rerun.chunk import RrdReader

    from shared.errors import BadInput

    out: dict[str, list[dict]] = defaultdict(list)
    try:
        chunks = list(RrdReader(str(path)).stream())
    except (RuntimeError, OSError, ValueError) as e:
        raise BadInput(f"{path}: not a readable rerun recording ({e})") from None
    for ch in chunks:
        rb = ch.to_record_batch()
        names = [n for n in rb.schema.names if ":" in n or n in ("trial", "set", "playback")]
        cols = {n: rb.column(n).to_pylist() for n in names}
        for i in range(rb.num_rows):
            out[ch.entity_path].append({n: cols[n][i] for n in names})
    return out
