"""The recognition report's open set on the bundled clips (4 classes, 3 performers): every
method counts every test clip once per held-out class, and the report's words come from the
numbers."""

from __future__ import annotations

import pytest

from shared.evaluation import open_set, report_markdown, verdicts
from shared.pss.space import performer


@pytest.fixture(scope="module")
def bundled_clips(bundled):
    from shared.io import find_clips, load_clip

    return [load_clip(f) for f in find_clips([bundled / "amc"])]


def test_open_set_counts_every_clip_for_every_method(bundled_clips):
    from shared.evaluation import minirocket_recognition, peers_available
    from shared.pss.space import ProtoSymbolSpace

    train = [c for c in bundled_clips if performer(c) != "HDM_dg"]
    test = [c for c in bundled_clips if performer(c) == "HDM_dg"]
    rocket = None
    if peers_available().get("minirocket") is None:
        kept: dict = {}
        minirocket_recognition(ProtoSymbolSpace.build(train), train, test, keep=kept)
        rocket = (kept["train_features"], kept["test_features"])
    res = open_set(train, test, minirocket=rocket)
    classes = sorted({c.label for c in train})
    assert [r["held_out"] for r in res["rows"]] == classes
    for row in res["rows"]:
        held = sum(c.label == row["held_out"] for c in test)
        for method in ("pss", "pss_distance", "pss_model") + (("minirocket",) if rocket is not None else ()):
            out, inn = row[method]["out"], row[method]["in"]
            assert out[1] == held and inn[1] == len(test) - held and 0 <= out[0] <= out[1] and 0 <= inn[0] <= inn[1]
        # "none of these" when either test says so: the union rejects at least what each rejects
        for key in ("out", "in"):
            assert row["pss"][key][0] >= max(row["pss_distance"][key][0], row["pss_model"][key][0])
            assert row["pss"][key][0] <= row["pss_distance"][key][0] + row["pss_model"][key][0]


def _result(out_rejected: int, in_rejected: int) -> dict:
    method = {"accuracy": 1.0, "per_class": {"a": [10, 10]}, "seconds_per_clip": 0.004, "truth": ["a"] * 10,
              "predictions": ["a"] * 10}
    return {"performers": ["p", "q"], "n_clips": 20, "classes": ["a"], "peers": {},
            "splits": {w: {"test": 10, "methods": {"pss": method}, "calibration": {
                "ece": 0.0, "mean_confidence": 1.0, "scheme": "across performers", "rejected_in_class": 0}}
                for w in ("p", "q")},
            "open_set": {w: {"rows": [{"held_out": "a", "pss": {"out": [out_rejected, 10], "in": [in_rejected, 100]},
                                       "pss_distance": {"out": [0, 10], "in": [0, 100]},
                                       "pss_model": {"out": [0, 10], "in": [0, 100]}}]} for w in ("p", "q")}}


@pytest.mark.parametrize("out_rejected, in_rejected, word", [(9, 5, "met"), (8, 5, "missed"), (10, 6, "missed")])
def test_the_open_set_verdict_is_computed(out_rejected, in_rejected, word):
    res = _result(out_rejected, in_rejected)
    res["verdicts"] = verdicts(res)
    text = report_markdown(res)
    line = next(x for x in text.splitlines() if x.startswith("Goal: at least 90 %"))
    assert line.endswith(f"**{word}**.")
