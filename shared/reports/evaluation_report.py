"""The recognition report (``reports/recognition/report.md``): the results of
:func:`shared.reports.evaluation.evaluate` as Markdown tables, with the goals' verdicts, the open set,
calibration and robustness, written by ``mirrorcoach evaluate recognition`` and ``make bench``."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from shared.pss.synthesis import DISTANCE_POWER
from shared.rates import with_interval
from shared.reports.evaluation import (
    ASSOCIATION_WEIGHTINGS,
    GOAL_ACCURACY,
    GOAL_ASSOCIATION,
    GOAL_MS,
    GOAL_OPEN_IN,
    GOAL_OPEN_OUT,
    TIMING_RUNS,
    open_rates,
)


def _unknown_confidence(res: dict, who: list[str]) -> dict[str, tuple[int, float, int]]:
    """Per test performer, the held-out-class clips of the open-set rows: how many, their mean
    confidence and how many had confidence >= 0.5 (rows written before it: left out)."""
    out = {}
    for w in who:
        conf = [c for row in (res.get("open_set", {}).get(w) or {}).get("rows", []) if "confidence" in row
                for c, novel in zip(row["confidence"], row["novel"]) if novel]
        if conf:
            out[w] = (len(conf), float(np.mean(conf)), int(sum(c >= 0.5 for c in conf)))
    return out


def separation(res: dict, method: str) -> tuple[float, float] | None:
    """How well a method's novelty separates the held-out classes' clips from the others', pooled
    over every split and held-out class. The novelty is a clip's score over its space's calibrated
    threshold (> 1: rejected), so pooling compares every space at its own calibration. Returns the
    ROC AUC, and the share of out-of-class clips rejected when every space's thresholds are scaled
    by the one common factor, chosen on the test clips themselves, that rejects at most
    ``GOAL_OPEN_IN`` of the in-class clips: what the calibration would reach were it off by the
    same factor everywhere (``None`` for results without scores)."""
    from sklearn.metrics import roc_auc_score

    novel, scores = [], []
    for split in res["open_set"].values():
        for row in split["rows"]:
            if method not in row.get("scores", {}):
                return None
            novel += row["novel"]
            scores += row["scores"][method]
    novel_a, s = np.array(novel, bool), np.array(scores, float)
    if not novel_a.any() or novel_a.all():
        return None
    inside = np.sort(s[~novel_a])
    allowed = int(np.floor(GOAL_OPEN_IN * len(inside) + 1e-9))  # in-class clips that may lie above it
    threshold = inside[max(len(inside) - 1 - allowed, 0)]
    return float(roc_auc_score(novel_a, s)), float(np.mean(s[novel_a] > threshold))


def _word(ok: bool) -> str:
    return "met" if ok else "missed"


def _counts(method: dict) -> tuple[int, int]:
    """(right, clips) of one method on one split, from its per-class counts."""
    right, total = (sum(c[i] for c in method["per_class"].values()) for i in (0, 1))
    return right, total


def report_markdown(res: dict) -> str:
    """The report's text; every verdict word comes from :func:`verdicts`."""
    splits = res["splits"]
    names = {"pss": "PSS: nearest class on positions, eq. 2.4 and the discriminant (ours, closed set)",
             "pss_shown": "PSS as `space recognize` shows it (open set on: \"none of these\" is not recognised)",
             "pss_point": "PSS: nearest point in the 3-D space (eq. 2.6)",
             "minirocket": "MiniRocket + ridge (aeon)", "dtw": "1-NN DTW (aeon, band 0.1), positions",
             "pss_knn3": "PSS, same distances: 3-NN", "pss_knn5": "PSS, same distances: 5-NN",
             "pss_logreg": "PSS, same distances: logistic regression on per-class distances (sklearn)",
             "pss_pose_floor": "PSS, a space for other styles (`--pose-floor 0.03`), closed set",
             "pss_pose_floor_shown": "PSS, a space for other styles (`--pose-floor 0.03`), as shown"}
    methods = [m for m in ("pss", "pss_shown", "minirocket", "dtw", "pss_point", "pss_knn3", "pss_knn5", "pss_logreg",
                           "pss_pose_floor", "pss_pose_floor_shown")
               if all(m in s["methods"] for s in splits.values())]
    who = list(splits)
    lines = ["# Recognition: the proto-symbol space against its peers", "",
             f"HDM05, {res['n_clips']} clips, {len(res['classes'])} classes, performers {', '.join(res['performers'])}; "
             "leave one performer out (the dev split is the one that tests dg). All methods see the same 30 fps clips; "
             "the peers read the space's z-scored joint positions in the heading frame. Written by "
             "`mirrorcoach evaluate recognition` (also `make bench`). Recognition's variance ceiling "
             "(`RECOGNITION_VAR_CEILING`) and the window its travel velocities are averaged over (`TRAVEL_WINDOW`) "
             "were chosen on the game studio's styles under the constraint that the dg split stay at 100 % closed "
             "set: the dg column is not held out from those choices, bd and bk are (though both were scored at "
             "three travel windows before its choice). So were the discriminant's weight in the label "
             "(`DISCRIMINANT_WEIGHT`; bd and bk were printed beside its choice set while it was explored) and the "
             "novelty model's level (`NOVELTY_QUANTILE`), whose constraint was dg's open set (at least 90 % of "
             "unknown and at most 5 % of known clips rejected): dg's open-set rates are not held out from it. "
             "The pose-floor rows are a space built for other styles "
             "(`--pose-floor`, not the default; docs/pss.md), its floor chosen the same way.", "",
             "| method | " + " | ".join(f"test {w} ({splits[w]['test']} clips)" for w in who) + f" | ms per clip (median; each clip's fastest of {TIMING_RUNS} runs) |",
             "|---|" + "---|" * (len(who) + 1)]
    for m in methods:
        cells = []
        for w in who:
            r = splits[w]["methods"][m]
            ok = sum(a for a, _ in r["per_class"].values())
            cells.append(f"{100 * r['accuracy']:.1f} % ({ok}/{splits[w]['test']})")
        ms = np.mean([splits[w]["methods"][m]["seconds_per_clip"] for w in who]) * 1e3
        lines.append(f"| {names[m]} | " + " | ".join(cells) + (f" | {ms:.1f} |" if np.isfinite(ms) else " | - |"))
    for name, why in res["peers"].items():
        if why:
            lines.append(f"\n{names[name]}: not run ({why}).")
    v = res["verdicts"]
    ms_max = max(splits[w]["methods"]["pss"]["seconds_per_clip"] for w in who) * 1e3
    accs = [splits[w]["methods"]["pss"]["accuracy"] for w in who]
    sizes = [_counts(splits[w]["methods"]["pss"])[1] for w in who]
    lines += ["", "## Goals", "",
              f"- At least {100 * GOAL_ACCURACY:.0f} % on every split, closed set: **{_word(v['accuracy_every_split'])}** "
              f"({', '.join(f'{100 * acc:.1f} %' for acc in accs)}).",
              *([f"- At least {100 * GOAL_ACCURACY:.0f} % on every split as `space recognize` shows it (open set on): "
                 f"**{_word(v['as_shown_every_split'])}** ("
                 + ", ".join(with_interval(*_counts(splits[w]["methods"]["pss_shown"])) for w in who)
                 + f"; in brackets each rate's exact 95 % interval: of {min(sizes)} clips one clip is "
                 f"{100 / min(sizes):.1f} points)."]
                if "as_shown_every_split" in v else []),
              f"- Never below the best peer of the same split by more than one clip: **{_word(v['within_one_clip_of_best_peer'])}**.",
              f"- At most {GOAL_MS:g} ms per clip in the library (HMM of the clip, distances, decision and the eq. 2.6 "
              f"placement): **{_word(v['ms_per_clip'])}** (worst split median {ms_max:.1f} ms).", ""]
    rates = open_rates(res, "pss")
    if rates is not None:
        lines += ["## Unknown motions (open set)", "",
                  "Every class held out in turn, the space built without it: its test clips should come back "
                  "\"none of these\", the other classes' should not.", "",
                  f"| method | out-of-class clips rejected | in-class clips rejected | AUC | out-of-class rejected at "
                  f"{100 * GOAL_OPEN_IN:.0f} % in-class, the thresholds scaled by one factor fitted on the test clips |",
                  "|---|---|---|---|---|"]

        def sep_cells(m):
            sep = separation(res, m)
            return "- | -" if sep is None else f"{sep[0]:.3f} | {100 * sep[1]:.1f} %"

        for m, what in (("pss", "PSS (ours): distance rule, discriminant ratio or novelty model"),
                        ("pss_distance", "PSS, the eq. 2.4 distance in its class's spread alone (level 0.98)"),
                        ("pss_ratio", "PSS, the discriminant ratio alone (shrinkage LDA on the HMMs, level 0.98)"),
                        ("pss_model", "PSS, the novelty model alone (ridge on the HMMs, level "
                                      f"{res.get('novelty_level', 0.95):g})"),  # 0.95: results written before it was kept
                        ("minirocket", "MiniRocket features, the same discriminant ratio or novelty model"),
                        ("dtw", "1-NN DTW, the eq. 2.4 distance rule (distance and ratio) on its distances")):
            d = open_rates(res, m)
            if d is not None:
                lines.append(f"| {what} | {100 * d[0]:.1f} % | {100 * d[1]:.1f} % | {sep_cells(m)} |")
        lines += ["", "A motion is \"none of these\" when any test says so (`shared/pss/recognition.py`): the "
                      "distances catch motions far from every class, the discriminant ratio (a shrinkage LDA on the "
                      "proto-symbols' HMMs) and the novelty model (a ridge classifier on the same) those between "
                      "classes, each calibrated across performers. The novelty model's features, the class "
                      "spreads and the discriminant ratio were chosen after seeing these same splits, and the novelty "
                      "model's level (chosen on the game studio's styles) after its earlier level had been scored on "
                      "them, so this table is optimistic for them."]
        sep = separation(res, "pss")
        if sep is not None and not v["open_set"]:
            lines += ["", "Where the goal is missed: " + (
                f"scaling every space's thresholds by one factor fitted on the test clips would reject "
                f"{100 * sep[1]:.1f} % of out-of-class clips at {100 * GOAL_OPEN_IN:.0f} % in-class, so what misses is "
                "the level of the thresholds calibrated from the training performers alone."
                if sep[1] >= GOAL_OPEN_OUT else
                f"even with every space's thresholds scaled by one factor fitted on the test clips, "
                f"{100 * sep[1]:.1f} % of out-of-class clips are rejected at {100 * GOAL_OPEN_IN:.0f} % in-class: a "
                "common correction of the calibrated level cannot meet the goal with these tests.")]
        lines += ["", "Per split (PSS, ours): a new performer may lie farther from the space's two than they lie "
                      "from each other, and the pooled rates average that away.", "",
                  "| test performer | out-of-class rejected | in-class rejected | out-of-class rejected, exact 95 % "
                  "interval (each clip is out of class once; in class it is counted once per held-out class, not "
                  "independent trials: no interval) |", "|---|---|---|---|"]
        for w in who:
            r = open_rates(res, "pss", only=w)
            if r is not None:
                rows = res["open_set"][w]["rows"]
                out = [sum(row["pss"]["out"][i] for row in rows) for i in (0, 1)]
                lines.append(f"| {w} | {100 * r[0]:.1f} % | {100 * r[1]:.1f} % | {with_interval(*out)} |")
        lines += ["", f"Goal: at least {100 * GOAL_OPEN_OUT:.0f} % out-of-class rejected, at most "
                      f"{100 * GOAL_OPEN_IN:.0f} % in-class rejected, on every test performer: "
                      f"**{_word(v['open_set'])}**.", "",
                  "| held-out class | " + " | ".join(f"{w}: rejected" for w in who) + " |", "|---|" + "---|" * len(who)]
        for k, cls in enumerate(res["classes"]):
            cells = []
            for w in who:
                row = res["open_set"][w]["rows"][k]
                cells.append(f"{row['pss']['out'][0]}/{row['pss']['out'][1]}")
            lines.append(f"| {cls} | " + " | ".join(cells) + " |")
        lines.append("")
    lines += ["## Confidence", "",
              "| split | mean confidence | expected calibration error | calibration | in-class clips rejected |",
              "|---|---|---|---|---|"]
    for w in who:
        c = splits[w]["calibration"]
        lines.append(f"| test {w} | {c['mean_confidence']:.3f} | {c['ece']:.3f} | {c['scheme']} | "
                     f"{c['rejected_in_class']}/{splits[w]['test']} |")
    lines += ["", "Correct: the answer shown (a known clip called \"none of these\" is not recognised; its confidence is "
                  "its credibility, `shared/pss/recognition.py`)."]
    unknown = _unknown_confidence(res, who)
    if unknown:
        lines += ["", "On motions the space does not hold (each class held out in turn, as in the open-set table), the "
                      "confidence `--json` gives for the nearest class (the text says only \"none of these\" when it rejects):", "",
                  "| test performer | clips | mean confidence | confidence >= 0.5 |", "|---|---|---|---|"]
        for w, (n, mean, high) in unknown.items():
            lines.append(f"| {w} | {n} | {mean:.3f} | {high} |")
    if all("robustness" in splits[w] for w in who):
        lines += ["", "## What a person expects not to change the label", "",
                  "The test clips changed as below, recognised as `space recognize` shows them (open set on); in "
                  "brackets, how many labels changed against the clips as they are.", "",
                  "| change | " + " | ".join(f"test {w}" for w in who) + " |", "|---|" + "---|" * len(who)]
        for how in splits[who[0]]["robustness"]:
            cells = [f"{100 * splits[w]['robustness'][how]['as_shown']:.1f} % ({splits[w]['robustness'][how]['changed']})"
                     for w in who]
            lines.append(f"| {how} | " + " | ".join(cells) + " |")
    lines += association_lines(res)
    lines += ["", "## Per class (ours / best peer, correct of total)", "",
              "| class | " + " | ".join(f"test {w}" for w in who) + " |", "|---|" + "---|" * len(who)]
    for cls in res["classes"]:
        cells = []
        for w in who:
            ms = splits[w]["methods"]
            a, n = ms["pss"]["per_class"].get(cls, (0, 0))
            peer = max((ms[p]["per_class"].get(cls, (0, 0))[0] for p in ("minirocket", "dtw") if p in ms), default=None)
            cells.append(f"{a}/{n}" + ("" if peer is None else f" / {peer}/{n}"))
        lines.append(f"| {cls} | " + " | ".join(cells) + " |")
    lines += ["", "## Confusions (ours)", ""]
    conf = [(w, t, p) for w in who for t, p in zip(splits[w]["methods"]["pss"]["truth"], splits[w]["methods"]["pss"]["predictions"]) if t != p]
    lines += [f"- test {w}: {t} recognised as {p}" for w, t, p in conf] or ["- none"]
    lines.append("")
    return "\n".join(lines)


def association_lines(res: dict) -> list[str]:
    """The association section: eq. 3.9 error per test performer and weighting, and its goal's verdict."""
    splits = res["splits"]
    who = [w for w in splits if ASSOCIATION_WEIGHTINGS[0] in splits[w].get("association", {})]
    if not who:
        why = next((s["association"]["not_run"] for s in splits.values() if "not_run" in s.get("association", {})), None)
        return ["", f"Association: not run ({why})."] if why else []
    names = {"distance": f"from its eq. 2.4 distances, (d_min / d)^{DISTANCE_POWER:g} (the default)",
             "inverse_distance": "from its point in the space, (d_min / d)^4 (the default before)"}
    lines = ["", "## Association on unseen performers (eq. 2.8)", "",
             "The torques of a 2.4 kg arm robot performing each test clip's right arm, estimated from the clip's motion "
             "alone by a space of the training clips with their torques (`space associate`); eq. 3.9's error "
             "|g - g_hat| / g, and how far below always answering the training clips' mean it lies. The weighting's "
             "power was chosen on inner splits (one training performer's space against the other's clips), though the "
             "test performers were scored in the same run (docs/pss.md, \"Association across performers\", gives "
             "every variant's numbers).", "",
             "| proto-symbols weighted | " + " | ".join(f"test {w}" for w in who) + " |", "|---|" + "---|" * len(who),
             "| the training clips' mean g | " + " | ".join(f"{100 * splits[w]['association']['training_mean']:.1f} %"
                                                         for w in who) + " |"]
    for m in ASSOCIATION_WEIGHTINGS:
        cells = [f"{100 * splits[w]['association'][m]['error']:.1f} % ({100 * splits[w]['association'][m]['below_mean']:.0f} % "
                 "below)" for w in who]
        lines.append(f"| {names[m]} | " + " | ".join(cells) + " |")
    lines += ["", f"Goal: at least {100 * GOAL_ASSOCIATION:.0f} % below the training mean on every test performer "
                  f"(the default weighting): **{_word(res['verdicts'].get('association', False))}**."]
    return lines


def write_report(res: dict, out: Path) -> Path:
    out.mkdir(parents=True, exist_ok=True)
    (out / "results.json").write_text(json.dumps(res, indent=1, default=float))
    path = out / "report.md"
    path.write_text(report_markdown(res))
    return path
