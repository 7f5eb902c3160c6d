"""The dashboard's drawing without a viewer: labels of a space placed so that none overlaps
another (shared.observe.labels), people turned to face the camera."""

from __future__ import annotations

import numpy as np


def test_space_labels_never_overlap_on_the_panel_they_are_placed_for():
    """shared.observe.labels: many classes crowded into one corner of a space, and a flat space (all
    on one line, as a session's first trial is): no two label boxes overlap on screen, no label
    covers another labelled point, the most important labels are kept, and a label with no free
    spot is left out (not piled on)."""
    from shared.observe import labels as lab

    rng = np.random.default_rng(3)
    crowded = np.vstack([rng.normal(0.0, 0.02, size=(12, 2)), [[5.0, 3.0], [-4.0, -2.0]]])
    flat = np.array([[-6.1, 0.0], [6.1, 0.0], [30.6, 0.0]])
    for pts, texts in ((crowded, [f"class{i}" for i in range(len(crowded))]),
                       (flat, ["target", "attempt 1", "shown after 1"])):
        panel = (600.0, 290.0)
        region = lab.frame(pts, panel)
        assert np.all(region[0] <= pts.min(axis=0)) and np.all(region[1] >= pts.max(axis=0))
        assert abs((region[1] - region[0])[0] / (region[1] - region[0])[1] - panel[0] / panel[1]) < 1e-9
        placed = lab.place(pts, texts, panel, region)
        assert placed[0].index == 0 and placed[0].text == texts[0]  # the first is always placed
        for i, p in enumerate(placed):
            assert all(not lab.overlap(p.box, q.box) for q in placed[i + 1:]), (p, placed)
        if len(pts) == 3:
            assert [p.index for p in placed] == [0, 1, 2]  # room for all three on a line
        else:
            assert 2 <= len(placed) < len(pts)  # the crowded ones cannot all have a label


def test_people_are_turned_to_face_the_camera():
    """shared.observe.dashboard.face_the_camera: a person whose left side points along -Z (facing
    -X, Y up) is turned about the up axis so that the left side points along +X (facing +Z, where
    the camera is); heights are unchanged; a skeleton with no left or right side is left as it is."""
    from shared.observe.dashboard import face_the_camera

    pos = np.array([[[0.0, 1.0, 0.0], [0.0, 0.9, -0.2], [0.0, 0.9, 0.2], [0.0, 1.7, 0.0]]] * 2)
    sides = ["centre", "left", "right", "head"]
    out = face_the_camera(pos, sides, up=1)
    lr = out[0, 1] - out[0, 2]
    assert lr[0] > 0.39 and abs(lr[2]) < 1e-9 and np.allclose(out[..., 1], pos[..., 1])
    assert np.allclose(np.linalg.norm(out[0] - out[0, 0], axis=1), np.linalg.norm(pos[0] - pos[0, 0], axis=1))
    z_up = pos[..., [0, 2, 1]]  # the same person with Z up: left along -Y
    out = face_the_camera(z_up, sides, up=2)
    assert (out[0, 1] - out[0, 2])[0] > 0.39 and np.allclose(out[..., 2], z_up[..., 2])
    assert face_the_camera(pos, ["centre"] * 4, up=1) is pos


def test_the_latency_table_counts_every_request_and_says_when_it_changed():
    """shared.observe.latency: requests and failures per service and verb, percentiles of the
    newest ones; written again only after new requests came (the observer asks between events)."""
    from shared.observe.latency import KEPT, LatencyTable

    t = LatencyTable()
    for ms, failed in ((1.0, False), (2.0, True), (3.0, False)):
        t.add("pss", "list", ms, failed)
    assert t.due
    table = t.markdown()
    assert "| pss | list | 3 | 1 | 2.0 | 2.9 | 3.0 |" in table and not t.due
    for i in range(KEPT + 10):  # only the newest KEPT are in the percentiles; every one is counted
        t.add("coach", "run", 1000.0 if i < 10 else 5.0, False)
    assert t.due and f"| coach | run | {KEPT + 10} | 0 | 5.0 | 5.0 | 5.0 |" in t.markdown()


def test_a_sessions_space_is_drawn_on_the_trial_whose_attempt_it_holds():
    """pss's space event and the coach's trial event come from two processes: the space names the
    trial itself (its last attempt), whichever event arrives first; before any attempt, none."""
    from shared.observe.dashboard import _space_trial

    names = ["squat", "attempt1-3f2a1c", "attempt2-9b0d4e", "attempt2-9b0d4e-goal1"]
    ev = {"space": "coach-demo", "info": {"proto_symbols": [{"name": n, "label": None} for n in names]}}
    assert _space_trial(ev) == 2
    assert _space_trial({"space": "coach-demo", "info": {"proto_symbols": [{"name": "squat"}]}}) is None
    assert _space_trial({"space": "coach-demo", "change": "deleted"}) is None
