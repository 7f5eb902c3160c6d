"""Static pictures of a rerun recording, for where the viewer cannot run (no display): the
recording is read back with rerun's own reader (``rerun.chunk.RrdReader``) and drawn with
matplotlib: skeletons side by side, the proto-symbol space with each session's path, the
per-trial and per-set curves, and the last transcript lines."""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path

import numpy as np


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
        names = [n for n in rb.schema.names if ":" in n or n in ("frame", "trial", "set")]
        cols = {n: rb.column(n).to_pylist() for n in names}
        for i in range(rb.num_rows):
            out[ch.entity_path].append({n: cols[n][i] for n in names})
    return out


def _values(rows, component):
    return [r[component] for r in rows if r.get(component) is not None]


def render(path, folder) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    data = read(path)
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    sessions = sorted({p.split("/")[2] for p in data if p.startswith("/skeletons/")})
    fig = plt.figure(figsize=(15, 9))
    # skeletons: the middle frame of the latest logged motions, side by side
    ax = fig.add_subplot(2, 3, (1, 2))
    colours = {"target": "tab:blue", "attempt": "tab:orange", "emphatic": "tab:red"}
    if sessions:
        s = sessions[-1]
        for kind, colour in colours.items():
            rows = [r for r in data.get(f"/skeletons/{s}/{kind}", []) if r.get("LineStrips3D:strips")]
            if not rows:
                continue
            frames = sorted({r["frame"] for r in rows if r.get("frame") is not None})
            mid = frames[len(frames) // 2] if frames else None
            row = [r for r in rows if r.get("frame") == mid][-1]
            for strip in row["LineStrips3D:strips"]:
                p = np.asarray(strip)
                ax.plot(p[:, 0], p[:, 1], color=colour, lw=2)
            ax.plot([], [], color=colour, label=kind)
        ax.set_title(f"session {s}: target | attempt | emphatic motion (middle frame)")
        ax.set_aspect("equal")
        ax.legend(loc="upper right")
    ax.set_xlabel("m")
    # the space of the latest session: proto-symbols, the attempts' path, the emphatic points
    ax = fig.add_subplot(2, 3, 3)
    if sessions:
        base = f"/space/coach-{sessions[-1]}"
        for name, style, label in (("target", "o", "x_t"), ("attempts", "s-", "x_p by trial"), ("emphatic", "^", "x_s")):
            rows = data.get(f"{base}/{name}", [])
            if rows:
                p = np.asarray(_values(rows, "Points3D:positions")[-1])
                ax.plot(p[:, 0], p[:, 1], style, label=label, markersize=7)
        ax.set_title("proto-symbol space (first two axes)")
        ax.legend()
    # curves: d_p and alpha per trial for every session
    ax = fig.add_subplot(2, 3, 4)
    for s in sessions:
        rows = data.get(f"/coach/{s}/d_p", [])
        if rows:
            ax.plot([r["trial"] for r in rows], [r["Scalars:scalars"][0] for r in rows], "o-", label=f"{s} d_p")
    ax.set_xlabel("trial")
    ax.set_title("d_p per trial")
    ax.legend(fontsize=7)
    ax = fig.add_subplot(2, 3, 5)
    estimates = sorted({p.split("/")[2] for p in data if p.startswith("/estimator/")})
    for e in estimates:
        rows = data.get(f"/estimator/{e}/scale", [])
        if rows:
            ax.plot([r["set"] for r in rows], [r["Scalars:scalars"][0] for r in rows], "o-", label=f"{e}: torque scale")
    ax.set_xlabel("conversation set")
    ax.set_title("estimator: the other's torque scale")
    ax.legend(fontsize=7)
    # transcript tail
    ax = fig.add_subplot(2, 3, 6)
    ax.axis("off")
    lines = []
    for p in sorted(x for x in data if x.startswith("/dialogue/")):
        lines += [f"{p.split('/')[-1]}  {t[0]}" for t in _values(data[p], "TextLog:text")]
    ax.text(0, 1, "\n".join(lines[-14:]) or "(no transcript)", va="top", family="monospace", fontsize=7)
    ax.set_title("dialogue transcript (last lines)")
    fig.suptitle(f"mirrorcoach recording {Path(path).name} (read back with rerun.chunk.RrdReader)")
    fig.tight_layout()
    out = folder / "dashboard_snapshot.png"
    fig.savefig(out, dpi=90)
    plt.close(fig)
    return [out]
