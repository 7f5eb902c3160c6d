"""Labels of a 2-D scatter that never overlap on screen (the dashboard's spaces).

A proto-symbol space is drawn in a 2-D view that shows a fixed region (:func:`region`), its points
mapped into it (:func:`frame`), so a point's place on screen is known from the panel's size in
pixels; a label's size is known from its text. Labels
are placed in order of importance, each at the first free spot among a few around its point (on
it, above, below, right, left, then further above and below); a label with no free spot is left
out (its point still names itself on hover). Free of rerun: the dashboard logs what this returns.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

CHAR_PX = 7.5  # the viewer's label font, measured on its screenshots: ~7 px per character at 12 px
LINE_PX = 18.0  # a label's box: its text's height with the box's padding
PAD_PX = 6.0
LABEL_DY = 11.0  # the viewer draws a point's label below it: the box's centre, pixels under the point
MARK_PX = 5.0  # the half size of a labelled point's marker, which no other label may cover
FIT = 0.9  # the share of the panel the region is taken to fill (less than the view's fit: on the safe side)


@dataclass(frozen=True)
class Placed:
    """A label at ``xy`` (data units, where the label's box is centred) for the point ``anchor``."""

    index: int
    text: str
    xy: tuple[float, float]
    anchor: tuple[float, float]
    box: tuple[float, float, float, float]  # x0, y0, x1, y1 on screen (pixels from the panel's centre, y down)


def frame(points, panel_px: tuple[float, float], margin: float = 0.1) -> tuple[np.ndarray, np.ndarray]:
    """The corners ``(lo, hi)`` of the box of data a 2-D view of ``panel_px`` (width, height)
    should show: the points' bounding box and a ``margin`` around it, widened to the panel's
    aspect (a flat or one-point space too: a box of no height draws nothing readable). The
    dashboard maps this box onto :func:`region`, the region the view shows."""
    pts = np.asarray(points, float).reshape(-1, 2)
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    size = hi - lo
    size = np.where(size > 1e-9 * max(1.0, float(size.max())), size, 0.0)
    if not size.any():
        size = np.array([1.0, 1.0]) * max(1.0, float(np.abs(pts).max()) * 0.2)
    aspect = panel_px[0] / panel_px[1]
    w, h = size * (1 + 2 * margin)
    w, h = max(w, h * aspect), max(h, w / aspect)
    centre = (lo + hi) / 2
    return centre - (w / 2, h / 2), centre + (w / 2, h / 2)


def region(panel_px: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    """The region a space's view shows, ``[-a, a] x [-1, 1]`` with ``a`` the panel's aspect: the
    same whatever the points (a view left to fit them fits all it has ever shown)."""
    a = panel_px[0] / panel_px[1]
    return np.array([-a, -1.0]), np.array([a, 1.0])


def _width(text: str) -> float:
    return len(text) * CHAR_PX + 2 * PAD_PX


def box_of(text: str, centre_px) -> tuple[float, float, float, float]:
    w, h = _width(text), LINE_PX
    return centre_px[0] - w / 2, centre_px[1] - h / 2, centre_px[0] + w / 2, centre_px[1] + h / 2


def overlap(a, b) -> bool:
    return a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]


def place(points, texts: list[str], panel_px: tuple[float, float], region) -> list[Placed]:
    """Labels for ``points`` (n x 2, data units) in order of importance (``texts[0]`` first), none
    overlapping another (or another labelled point) on a panel of ``panel_px`` pixels that shows
    ``region`` (:func:`region`, or any box of data). A label whose every spot is taken is left out."""
    pts = np.asarray(points, float).reshape(-1, 2)
    lo, hi = (np.asarray(c, float) for c in region)
    centre, scale = (lo + hi) / 2, FIT * float(min(panel_px[0] / (hi - lo)[0], panel_px[1] / (hi - lo)[1]))
    marks = {i: ((q := (p - centre) * scale)[0] - MARK_PX, q[1] - MARK_PX, q[0] + MARK_PX, q[1] + MARK_PX)
             for i, (p, t) in enumerate(zip(pts, texts)) if t}
    placed: list[Placed] = []
    for i, (p, text) in enumerate(zip(pts, texts)):
        if not text:
            continue
        px = (p - centre) * scale
        w = _width(text)
        for dx, dy in ((0, 0), (0, -LINE_PX - 2 * MARK_PX), (w / 2 + PAD_PX, -LABEL_DY), (-w / 2 - PAD_PX, -LABEL_DY),
                       (0, LINE_PX), (0, -2 * LINE_PX - 2 * MARK_PX), (0, 2 * LINE_PX)):
            at = px + (dx, dy)
            box = box_of(text, at + (0.0, LABEL_DY))
            if all(not overlap(box, q.box) for q in placed) and all(not overlap(box, m) for k, m in marks.items()
                                                                      if k != i):
                xy = at / scale + centre
                placed.append(Placed(i, text, (float(xy[0]), float(xy[1])), (float(p[0]), float(p[1])), box))
                break
    return placed
