"""Studies with people: the protocol of thesis fig. 4.3 / Table 4.2 with real
participants, and a coach seat for chapter 5. Bus-free: the CLI (``mirrorcoach study``) wires
it to the coach service.

A study is a folder:

* ``plan.json``: the participants, each one's order of cases, the target, trials per case and
  the seed. Orders are **counterbalanced** (a Williams balanced Latin square over the cases:
  every case comes equally often in every position and, for an even number of cases, after
  every other case equally often), the square's rows assigned to participants in a seeded
  random order (:func:`plan`);
* ``log.jsonl``: every event (the plan, each trial, each seat answer), one JSON object per
  line, appended and ``fsync``-ed before the command returns, so a killed command loses at
  most the line it was writing; :func:`read_log` skips a torn last line;
* ``show/``: the motions to show participants (the target, then each trial's emphatic motion).

Every trial is also kept by the coach service (one session per participant and case,
``study-<id>-<participant>-case<c>``); a trial the coach completed whose log line was lost is
taken back from the coach (:func:`missing_trials`).

``export`` writes the tidy table of :mod:`shared.reproduce.tidy` (world ``people``), which the
report's statistics read exactly as they read the simulated runs' ``tidy.csv``.
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

import numpy as np

from shared.errors import BadInput, Conflict

#: the per-person alpha sweep of thesis 5.4.1 (figs. 5.7, 5.8): case 10 + k shows alpha
#: ``SWEEP_ALPHAS[k]`` without adverb, case 30 + k the same alpha with Table 4.1's adverb; each
#: participant's best alphas then set cases 5 and 6 (EMU-Model 2, :func:`emu2_from_sweep`)
SWEEP_ALPHAS = (0.0, 1.25, 1.5, 1.75, 2.0, 2.25, 2.5)
SWEEP_CASES = {**{10 + k: (a, None) for k, a in enumerate(SWEEP_ALPHAS)},
               **{30 + k: (a, "table") for k, a in enumerate(SWEEP_ALPHAS)}}
#: the cases a study can run (thesis Table 4.2, 6.1, 6.4, and the sweep) and their policies
STUDY_CASES = (1, 2, 3, 4, 5, 6, 7, 8, *SWEEP_CASES)
ADVERB_CHOICES = ("a little more", "more", "much more")


def williams(n: int) -> list[list[int]]:
    """A Williams balanced Latin square of ``n`` treatments (rows: orders of 0..n-1); for odd
    ``n`` it and its mirror (2n rows)."""
    first = [0]
    lo, hi = 1, n - 1
    for k in range(1, n):
        first.append(lo if k % 2 else hi)
        lo, hi = (lo + 1, hi) if k % 2 else (lo, hi - 1)
    rows = [[(x + r) % n for x in first] for r in range(n)]
    return rows + [row[::-1] for row in rows] if n % 2 else rows


def plan(participants: int, cases: list[int], seed: int, trials: int = 4, emu2: dict | None = None,
         aeu_scale: float | None = None, aeu_thresholds: dict | None = None) -> dict:
    """The counterbalanced, seeded plan (module docstring). ``emu2`` maps participant id to
    EMU-Model 2's alpha without / with adverb (cases 5 and 6); ``aeu_scale`` converts our
    distances to the thesis's units for AEU-Models 1 and 2 (cases 7 and 8); ``aeu_thresholds``
    ``{7: [t1, t2], 8: [...]}`` replaces a case's thesis thresholds by ones fitted from human
    coaches (:func:`shared.coaching.policies.fit_aeu`, ``study aeu``)."""
    aeu_thresholds = {int(k): [float(t) for t in v] for k, v in (aeu_thresholds or {}).items()}
    if not 1 <= participants <= 500:
        raise BadInput(f"participants must be 1 to 500, got {participants}", field="participants")
    if not cases or len(set(cases)) != len(cases) or any(c not in STUDY_CASES for c in cases):
        raise BadInput(f"cases must be distinct, from {', '.join(map(str, STUDY_CASES))}; got {cases}", field="cases")
    if not 2 <= trials <= 20:
        raise BadInput(f"trials per case must be 2 to 20, got {trials}", field="trials")
    ids = [f"P{i + 1:02d}" for i in range(participants)]
    if {5, 6} & set(cases):
        missing = [p for p in ids if p not in (emu2 or {})]
        if missing:
            raise BadInput(f"cases 5 and 6 need EMU-Model 2's alpha per participant (from their own alpha sweep); "
                           f"missing for {', '.join(missing[:5])}", field="emu2")
    if any(c in cases and c not in aeu_thresholds for c in (7, 8)) and not aeu_scale:
        raise BadInput("cases 7 and 8 need the AEU calibration (thesis units per our distance unit, "
                       "`reproduce` reports one) or thresholds fitted from human coaches (`study aeu`)", field="aeu_scale")
    square = williams(len(cases))
    rng = np.random.default_rng(seed)
    rows = [square[k % len(square)] for k in range(participants)]
    order = rng.permutation(participants)  # which participant takes which row: seeded, random
    return {"participants": {ids[j]: [cases[x] for x in rows[int(k)]] for j, k in zip(range(participants), order)},
            "cases": list(cases), "trials": trials, "seed": seed, "emu2": emu2 or {}, "aeu_scale": aeu_scale,
            "aeu_thresholds": {str(k): v for k, v in aeu_thresholds.items()},
            "design": "Williams balanced Latin square, rows assigned by a seeded permutation"}


def case_name(case: int) -> str:
    """How reports name a case: ``case 3``, or ``sweep alpha 1.5 + adverb``."""
    if case in SWEEP_CASES:
        a, adverb = SWEEP_CASES[case]
        return f"sweep alpha {a:g}" + (" + adverb" if adverb else "")
    return f"case {case}"


def expand_cases(text: str) -> list[int]:
    """``--cases`` as given: numbers separated by commas, ``sweep`` for the 14 sweep cases."""
    out: list[int] = []
    for item in (x.strip() for x in text.split(",")):
        if not item:
            continue
        if item == "sweep":
            out += list(SWEEP_CASES)
            continue
        try:
            out.append(int(item))
        except ValueError:
            raise BadInput(f"--cases takes case numbers and 'sweep' separated by commas, got {item!r}",
                           field="cases") from None
    return out


def emu2_from_sweep(p: dict, events: list[dict]) -> dict[str, list[float]]:
    """EMU-Model 2 per participant (thesis 5.4.1, fig. 5.8): of the sweep's alphas, the one whose
    session ended lowest (``R_l = d_l / d_1`` at the last trial, eq. 4.5), without and with the
    adverb. A participant needs every trial of at least two alphas on each side."""
    from shared.coaching.policies import best_alpha

    done = trials_of(events)
    out = {}
    for person in p["participants"]:
        pair = []
        for adverb in (None, "table"):
            ratio = {}
            for case, (a, adv) in SWEEP_CASES.items():
                rows = sorted(done.get((person, case), []), key=lambda e: e["trial"])
                if adv == adverb and len(rows) == p["trials"] and rows[0]["d_p"] > 0:
                    ratio[a] = rows[-1]["d_p"] / rows[0]["d_p"]
            if len(ratio) < 2:
                break
            pair.append(best_alpha(ratio))
        if len(pair) == 2:
            out[person] = pair
    return out


def policy(p: dict, participant: str, case: int) -> dict:
    """The coach's policy for one case (Table 4.2, 6.1, 6.4; the sweep's)."""
    if case in SWEEP_CASES:
        a, adverb = SWEEP_CASES[case]
        return {"kind": "fixed", "alpha": a, "adverb": adverb}
    if case == 1:
        return {"kind": "fixed", "alpha": 0.0, "adverb": None}
    if case == 2:
        return {"kind": "fixed", "alpha": 0.0, "adverb": "more like this"}
    if case in (3, 4):
        return {"kind": "fixed", "alpha": 2.0, "adverb": None if case == 3 else "table"}
    if case in (5, 6):
        alphas = p["emu2"][participant]
        a = float(alphas[case - 5] if isinstance(alphas, (list, tuple)) else alphas)
        return {"kind": "fixed", "alpha": a, "adverb": None if case == 5 else "table"}
    fitted = (p.get("aeu_thresholds") or {}).get(str(case))
    if fitted:
        return {"kind": "aeu1" if case == 7 else "aeu2", "alpha": 2.0, "thresholds": fitted}
    return {"kind": "aeu1" if case == 7 else "aeu2", "alpha": 2.0, "calibration": float(p["aeu_scale"])}


# ---------------------------------------------------------------------------- the log
def append(folder: Path, event: dict) -> None:
    """One event, appended and on disk before returning. A line torn by a kill is cut off
    first (its trial is still the coach's, and :func:`missing_trials` brings it back)."""
    line = json.dumps({**event, "time": time.time()}, separators=(",", ":")) + "\n"
    path = Path(folder) / "log.jsonl"
    if path.exists():
        with open(path, "r+b") as f:
            data = f.read()
            if data and not data.endswith(b"\n"):
                f.truncate(data.rfind(b"\n") + 1)
    with open(path, "a", encoding="utf-8") as f:
        f.write(line)
        f.flush()
        os.fsync(f.fileno())


def read_log(folder: Path) -> list[dict]:
    path = Path(folder) / "log.jsonl"
    if not path.exists():
        raise BadInput(f"{folder} is not a study (no log.jsonl); start one with `mirrorcoach study init`")
    out = []
    lines = path.read_text(encoding="utf-8").splitlines()
    for n, line in enumerate(lines):
        try:
            out.append(json.loads(line))
        except ValueError:
            if n == len(lines) - 1:  # a line torn by a kill: the coach still has the trial
                break
            raise BadInput(f"{path}, line {n + 1}: not JSON (edited by hand?)") from None
    return out


def load(folder: Path) -> dict:
    events = read_log(folder)
    if not events or events[0].get("event") != "plan":
        raise BadInput(f"{folder}/log.jsonl does not start with the study's plan")
    return events[0]["plan"]


def session_name(study: str, participant: str, case: int) -> str:
    return f"study-{study}-{participant}-case{case}"[:64]


def trials_of(events: list[dict]) -> dict[tuple[str, int], list[dict]]:
    out: dict[tuple[str, int], list[dict]] = {}
    for e in events:
        if e.get("event") == "trial":
            out.setdefault((e["participant"], e["case"]), []).append(e)
    return out


def next_step(p: dict, events: list[dict], participant: str | None = None) -> dict | None:
    """The next (participant, case, trial) to run: the named participant's, or the first
    participant with work left; None when the study (or the participant) is done."""
    done = trials_of(events)
    who = [participant] if participant else list(p["participants"])
    for person in who:
        if person not in p["participants"]:
            raise BadInput(f"no participant {person!r} in this study ({', '.join(p['participants'])})",
                           field="participant")
        for case in p["participants"][person]:
            n = len(done.get((person, case), []))
            if n < p["trials"]:
                return {"participant": person, "case": case, "trial": n + 1}
    return None


def missing_trials(events: list[dict], participant: str, case: int, coach_trials: list[dict]) -> list[dict]:
    """Trials the coach kept whose log line was lost (a kill between the two)."""
    have = {e["trial"] for e in trials_of(events).get((participant, case), [])}
    return [t for t in coach_trials if t["number"] not in have]


def trial_event(participant: str, case: int, t: dict, shown: str | None, recovered: bool = False) -> dict:
    return {"event": "trial", "participant": participant, "case": case, "trial": int(t["number"]),
            "d_p": float(t["d_p"]), "alpha": float(t["alpha_shown"]), "adverb": t.get("adverb"), "shown_next": shown,
            **({"recovered_from_coach": True} if recovered else {})}


def tidy(events: list[dict], target: str) -> list[dict]:
    """The study's trials as :mod:`shared.reproduce.tidy` rows (world ``people``)."""
    return [{"world": "people", "family": "", "target": target, "condition": case_name(e["case"]),
             "unit": e["participant"], "trial": e["trial"], "d_p": e["d_p"], "alpha": e["alpha"], "adverb": e["adverb"]}
            for e in events if e.get("event") == "trial"]


def seat_rows(events: list[dict]) -> list[dict]:
    return [e for e in events if e.get("event") == "seat"]


def seat_statistics(rows: list[dict]) -> dict:
    """Chapter 5 from the coach seat: the d_p each adverb was said for, per coach and pooled
    (fig. 5.4, 5.5), Table 5.1 (ANOVA and Tukey-Kramer on the pooled d_p by adverb) and, from
    the demonstrations, EMU-Model 1 per coach (eq. 5.5, and eq. 5.9 corrected on d_h)."""
    from shared.coaching.policies import fit_emu1, fit_emu1_corrected
    from shared.reproduce.coaching_stats import tukey_table

    by = {a: [r["d_p"] for r in rows if r["adverb"] == a] for a in ADVERB_CHOICES}
    coaches = sorted({r["coach"] for r in rows})
    per_coach = {c: {a: [r["d_p"] for r in rows if r["coach"] == c and r["adverb"] == a] for a in ADVERB_CHOICES}
                 for c in coaches}
    table = tukey_table({a: np.asarray(v, float) for a, v in by.items()}) if all(len(v) >= 2 for v in by.values()) else None
    emu1 = {}
    for c in coaches:
        demos = [r for r in rows if r["coach"] == c and "d_s" in r]
        if len(demos) >= 2:
            corrected, _ = fit_emu1_corrected([(r["x_t"], r["x_p"], r["x_s"]) for r in demos])
            emu1[c] = {"n": len(demos), "alpha_eq5_5": fit_emu1([r["d_p"] for r in demos], [r["d_s"] for r in demos]),
                       "alpha_eq5_9": corrected}
    return {"by_adverb": by, "per_coach": per_coach, "table_5_1": table, "emu1": emu1}


def seat_report(rows: list[dict], folder: Path) -> list[str]:
    """The coach seat's section of a study report, with figs. 5.4-5.6 written beside it."""
    from shared.reproduce.coaching_report import plot_figure
    from shared.reproduce.coaching_stats import tukey_markdown

    st = seat_statistics(rows)
    lines = ["## Coach seat (chapter 5)", "", "| adverb | answers | mean d_p | sd |", "|---|---|---|---|"]
    for a, v in st["by_adverb"].items():
        lines.append(f"| {a} | {len(v)} | " + (f"{np.mean(v):.2f} | " if v else "- | ")
                     + (f"{np.std(v, ddof=1):.2f} |" if len(v) > 1 else "- |"))
    lines += ["", *(["**Table 5.1**:", "", *tukey_markdown(st["table_5_1"])] if st["table_5_1"] else
                    ["Table 5.1 needs at least two answers for every adverb."]), ""]
    y = {a: k for k, a in enumerate(ADVERB_CHOICES)}
    f54 = plot_figure(Path(folder) / "fig5_4.png", "d_p of each attempt and the adverb said (fig. 5.4)", "d_p", "adverb",
               {c: ([r["d_p"] for r in rows if r["coach"] == c], [y[r["adverb"]] for r in rows if r["coach"] == c],
                    None, "o") for c in st["per_coach"]}, None)
    f55 = plot_figure(Path(folder) / "fig5_5.png", "mean d_p per adverb (fig. 5.5)", "adverb (0 a little more, 1 more, "
               "2 much more)", "d_p", {c: ([y[a] for a, v in per.items() if v], [np.mean(v) for v in per.values() if v],
                                        None, "o-") for c, per in st["per_coach"].items()}, [0, 1, 2])
    lines += [f"![fig. 5.4]({f54}) ![fig. 5.5]({f55})", ""]
    demos = [r for r in rows if "d_s" in r]
    if demos:
        f56 = plot_figure(Path(folder) / "fig5_6.png", "d_s against d_p, per coach (fig. 5.6)", "d_p", "d_s",
                   {c: ([r["d_p"] for r in demos if r["coach"] == c], [r["d_s"] for r in demos if r["coach"] == c],
                        None, "o") for c in sorted({r["coach"] for r in demos})}, None)
        lines += [f"![fig. 5.6]({f56})", "", "| coach | demonstrations | EMU-Model 1, eq. 5.5 | corrected, eq. 5.9 |",
                  "|---|---|---|---|"]
        lines += [f"| {c} | {e['n']} | {e['alpha_eq5_5']:.2f} | {e['alpha_eq5_9']:.2f} |" for c, e in st["emu1"].items()]
        lines.append("")
    return lines


def sweep_report(p: dict, events: list[dict], folder: Path) -> list[str]:
    """The alpha sweep's section of a study report (figs. 5.7, 5.8 for people): R at the last
    trial per participant and alpha, its mean, and each participant's EMU-Model 2 alphas."""
    from shared.reproduce.coaching_report import plot_figure

    done = trials_of(events)
    people = list(p["participants"])
    last = f"R_{p['trials']}"
    series, lines = {}, [f"## Alpha sweep (thesis 5.4.1, figs. 5.7 / 5.8): {last} per participant", "",
                         "| participant | adverb | " + " | ".join(f"alpha {a:g}" for a in SWEEP_ALPHAS) + " |",
                         "|---|---|" + "---|" * len(SWEEP_ALPHAS)]
    for adverb in (None, "table"):
        cases = [c for c, (_, adv) in SWEEP_CASES.items() if adv == adverb]
        grid = np.full((len(people), len(cases)), np.nan)
        for i, person in enumerate(people):
            for j, case in enumerate(cases):
                rows = sorted(done.get((person, case), []), key=lambda e: e["trial"])
                if len(rows) == p["trials"] and rows[0]["d_p"] > 0:
                    grid[i, j] = rows[-1]["d_p"] / rows[0]["d_p"]
            lines.append(f"| {person} | {'Table 4.1' if adverb else 'none'} | "
                         + " | ".join("-" if np.isnan(v) else f"{v:.3f}" for v in grid[i]) + " |")
        have = ~np.all(np.isnan(grid), axis=0)
        if have.any():
            series[f"{'with' if adverb else 'without'} adverb"] = (
                [a for a, h in zip(SWEEP_ALPHAS, have) if h], np.nanmean(grid[:, have], axis=0), None, "o-")
    emu2 = emu2_from_sweep(p, events)
    lines += ["", "EMU-Model 2 (each participant's alpha that ended lowest, without / with the adverb): "
              + (", ".join(f"{k} {v[0]:g} / {v[1]:g}" for k, v in emu2.items()) or "no participant has finished "
                 "two alphas on both sides yet") + ". `study init --cases 5,6 --emu2 " + str(folder)
              + "` coaches them with these alphas.", ""]
    if series:
        f57 = plot_figure(Path(folder) / "fig5_7.png", f"{last} against alpha, mean over participants (fig. 5.7)", "alpha",
                   last, series, list(SWEEP_ALPHAS))
        lines.append(f"![fig. 5.7]({f57})")
    if emu2:
        f58 = plot_figure(Path(folder) / "fig5_8.png", "EMU-Model 2's alpha per participant (fig. 5.8)", "participant",
                   "best alpha of the sweep", {"without adverb": (list(range(len(emu2))), [v[0] for v in emu2.values()],
                                                                  None, "o"),
                                               "with adverb": (list(range(len(emu2))), [v[1] for v in emu2.values()],
                                                               None, "s")}, list(range(len(emu2))))
        lines.append(f"![fig. 5.8]({f58})")
    return lines + [""]


def check_new(folder: Path) -> None:
    if (Path(folder) / "log.jsonl").exists():
        raise Conflict(f"{folder} already holds a study; choose another folder (a study's log is never overwritten)")
