"""The recognition report's open set on the bundled clips (4 classes, 3 performers): every
method counts every test clip once per held-out class, and the report's words come from the
numbers."""

from __future__ import annotations

import pytest

from shared.pss.space import performer
from shared.reports.evaluation import open_set, verdicts
from shared.reports.evaluation_report import report_markdown, separation


@pytest.fixture(scope="module")
def bundled_clips(bundled):
    from shared.io import find_clips, load_clip

    return [load_clip(f) for f in find_clips([bundled / "amc"])]


@pytest.mark.slow
def test_open_set_counts_every_clip_for_every_method(bundled_clips):
    from shared.pss.space import ProtoSymbolSpace
    from shared.reports.evaluation import minirocket_recognition, peers_available

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
        for method in ("pss", "pss_distance", "pss_ratio", "pss_model") + (("minirocket",) if rocket is not None else ()):
            out, inn = row[method]["out"], row[method]["in"]
            assert out[1] == held and inn[1] == len(test) - held and 0 <= out[0] <= out[1] and 0 <= inn[0] <= inn[1]
        # every clip's score is kept, and the counts are its scores above 1
        assert row["novel"] == [c.label == row["held_out"] for c in test]
        for method, scores in row["scores"].items():
            assert len(scores) == len(test)
            assert sum(s > 1.0 for s, n in zip(scores, row["novel"]) if n) == row[method]["out"][0]
            assert sum(s > 1.0 for s, n in zip(scores, row["novel"]) if not n) == row[method]["in"][0]
        assert row["scores"]["pss"] == [max(d, r, m) for d, r, m in zip(
            row["scores"]["pss_distance"], row["scores"]["pss_ratio"], row["scores"]["pss_model"])]
        # the confidence the user is given for every clip; a rejected one at most its credibility (<= 0.05)
        assert len(row["confidence"]) == len(test) and all(0.0 <= c <= 1.0 for c in row["confidence"])
        assert all(c <= 0.05 for c, s in zip(row["confidence"], row["scores"]["pss"]) if s > 1.0)
        # "none of these" when any test says so: the union rejects at least what each rejects
        tests = ("pss_distance", "pss_ratio", "pss_model")
        for key in ("out", "in"):
            assert row["pss"][key][0] >= max(row[m][key][0] for m in tests)
            assert row["pss"][key][0] <= sum(row[m][key][0] for m in tests)


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
    # and per split: here the other split rejects every in-class clip, which pooling halves
    res["open_set"]["q"]["rows"][0]["pss"]["in"] = [100, 100]
    text = report_markdown(res)
    lines = text.splitlines()
    assert any(x.startswith(f"| p | {10 * out_rejected:.1f} % | {float(in_rejected):.1f} % | ") for x in lines)
    assert any(x.startswith("| q | " + f"{10 * out_rejected:.1f} % | 100.0 % | ") for x in lines)
    # the goal holds on every test performer, not on the pooled rates (5 + 10 of 200 in-class is 7.5 %
    # pooled, 5 % and 10 % per performer: the one at 10 % misses it whatever the pooled rate)
    res["open_set"]["q"]["rows"][0]["pss"]["in"] = [10, 100]
    assert verdicts(res)["open_set"] is False
    res["open_set"]["q"]["rows"][0]["pss"]["in"] = [in_rejected, 100]
    assert verdicts(res)["open_set"] is (word == "met")


def test_the_rates_a_goal_is_judged_on_come_with_their_exact_intervals():
    """A split's rate as shown and its out-of-class rejections are given with their exact
    (Clopper-Pearson) 95 % intervals: 9 of 10 is 55.5-99.7 %, 10 of 10 69.2-100 %."""
    res = _result(9, 5)
    for w, right in (("p", 9), ("q", 10)):
        res["splits"][w]["methods"]["pss_shown"] = {"accuracy": right / 10, "per_class": {"a": [right, 10]},
                                                   "seconds_per_clip": 0.004}
    res["verdicts"] = verdicts(res)
    lines = report_markdown(res).splitlines()
    shown = next(x for x in lines if "as `space recognize` shows it (open set on):" in x)
    assert "**missed** (90.0 % of 10 (55.5-99.7 %), 100.0 % of 10 (69.2-100.0 %);" in shown, shown
    assert "of 10 clips one clip is 10.0 points" in shown, shown
    assert any(x.startswith("| p | 90.0 % | 5.0 % | 90.0 % of 10 (55.5-99.7 %) |") for x in lines), lines


def test_the_report_gives_the_confidence_on_motions_the_space_does_not_hold():
    res = _result(9, 5)
    res["verdicts"] = verdicts(res)
    assert "mean confidence | confidence >= 0.5" not in report_markdown(res)  # rows written before it: left out
    for w, conf in (("p", [0.9, 0.02, 0.6, 0.1]), ("q", [0.01, 0.03])):
        row = res["open_set"][w]["rows"][0]
        row["novel"] = [True] * len(conf) + [False]
        row["confidence"] = conf + [1.0]  # a known clip's confidence does not count
    lines = report_markdown(res).splitlines()
    assert "| p | 4 | 0.405 | 2 |" in lines and "| q | 2 | 0.020 | 0 |" in lines


def _with_scores(res: dict, inside: list[float], outside: list[float]) -> dict:
    """One split's row carries these novelty scores (the other split's row none of its own)."""
    for k, w in enumerate(("p", "q")):
        row = res["open_set"][w]["rows"][0]
        row["novel"] = [False] * len(inside) + [True] * len(outside) if k == 0 else []
        row["scores"] = {m: (inside + outside if k == 0 else []) for m in ("pss", "pss_distance", "pss_model")}
    return res


def test_separation_is_the_auc_and_the_best_threshold_on_the_test_clips():
    inside = [0.1 * i for i in range(100)]  # 0 .. 9.9
    res = _with_scores(_result(5, 4), inside, [9.55, 9.65, 20.0, 0.5])
    auc, upper = separation(res, "pss")
    # at most 5 of 100 in-class above the threshold: it is 9.4, and 3 of 4 out-of-class lie above it
    assert upper == pytest.approx(0.75)
    # each out-of-class clip above how many in-class clips (a tie counts half): 96, 97, 100, 5.5
    assert auc == pytest.approx((96 + 97 + 100 + 5.5) / 400)
    res["verdicts"] = verdicts(res)
    text = report_markdown(res)
    assert "what misses is the level of the thresholds" not in text  # 75 % < 90 %
    assert "a common correction of the calibrated level cannot meet the goal" in text
    res = _with_scores(_result(5, 4), inside, [10.0 + i for i in range(9)] + [0.0])
    res["verdicts"] = verdicts(res)
    assert separation(res, "pss")[1] == pytest.approx(0.9)
    assert "what misses is the level of the thresholds calibrated from the training performers alone" in report_markdown(res)
    res = _with_scores(_result(9, 5), inside, [10.0] * 10)
    res["verdicts"] = verdicts(res)
    assert "Where the goal is missed" not in report_markdown(res)
    assert separation(_result(9, 5), "pss") is None  # results written before the scores were kept


def test_a_clip_s_time_is_its_fastest_run_and_its_answer_the_first():
    """Every method's time per clip is the fastest of ``TIMING_RUNS`` runs (what else the machine
    does only adds), its answer the first run's (a clock that each run moves on, never the wall's)."""
    from shared.reports.evaluation import TIMING_RUNS, timed

    calls: list[str] = []
    now = [0.0]

    def run(clip):
        calls.append(clip)
        now[0] += 5.0 if len(calls) % TIMING_RUNS == 1 else 1.0 + 0.5 * (len(calls) % TIMING_RUNS)
        return f"{clip}{len(calls)}"

    answers, secs = timed(run, ["a", "b"], clock=lambda: now[0])
    assert TIMING_RUNS >= 2 and calls == ["a"] * TIMING_RUNS + ["b"] * TIMING_RUNS
    assert answers == ["a1", f"b{TIMING_RUNS + 1}"]
    assert secs == [min(1.0 + 0.5 * (k % TIMING_RUNS) for k in range(2, TIMING_RUNS + 1))] * 2


def test_the_novelty_model_row_names_the_level_its_results_were_made_at():
    res = _result(9, 5)
    res["verdicts"] = verdicts(res)
    assert "novelty model alone (ridge on the HMMs, level 0.95)" in report_markdown(res)  # written before it was kept
    res["novelty_level"] = 0.97
    assert "novelty model alone (ridge on the HMMs, level 0.97)" in report_markdown(res)


@pytest.mark.parametrize("below, word", [((0.35, 0.31), "met"), ((0.35, 0.25), "missed")])
def test_the_association_verdict_is_computed_on_every_test_performer(below, word):
    res = _result(9, 5)
    for w, b in zip(("p", "q"), below):
        res["splits"][w]["association"] = {"training_mean": 0.4, "distance": {"error": 0.4 * (1 - b), "below_mean": b},
                                           "inverse_distance": {"error": 0.3, "below_mean": 0.25}}
    res["verdicts"] = verdicts(res)
    lines = report_markdown(res).splitlines()
    assert next(x for x in lines if x.startswith("Goal: at least 30 % below")).endswith(f"**{word}**.")
    assert "| the training clips' mean g | 40.0 % | 40.0 % |" in lines
    res["splits"]["p"]["association"] = res["splits"]["q"]["association"] = {"not_run": "no right-arm channels"}
    res["verdicts"] = verdicts(res)
    assert "association" not in res["verdicts"] and "Association: not run (no right-arm channels)." in report_markdown(res)
