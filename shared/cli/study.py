"""CLI of studies with people: ``study init | next | attempt | seat | export | report``.

See :mod:`shared.reports.study` for the folder, the counterbalanced plan and why no trial is lost."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from shared.cli.common import (
    BACKGROUND_HELP,
    JSON_OPTION,
    LABEL_HELP,
    SKELETON_HELP,
    SPACE_HELP,
    app,
    client,
    fail,
    read_clip,
    say_if_unguarded,
    space_fields,
    wire,
)

study_app = typer.Typer(help="Run the thesis's studies with people: participants send their own attempts (fig. 4.3, "
                             "Table 4.2) and human coaches name adverbs from a coach seat (chapter 5).",
                        no_args_is_help=True)
app.add_typer(study_app, name="study")

FOLDER = typer.Argument(..., help="The study's folder (made by `study init`).")


def _study(folder: Path) -> tuple[dict, list[dict]]:
    from shared.reports.study import load, read_log

    return load(folder), read_log(folder)


def _save_shown(folder: Path, name: str, clip, fps: float) -> Path:
    from shared.io import save_clip

    out = folder / "show"
    out.mkdir(exist_ok=True)
    clip = clip.resample(fps) if clip.fps != fps else clip
    path = out / (f"{name}.bvh" if clip.skeleton is not None else f"{name}.npz")
    save_clip(clip, path)
    return path


def _study_id(folder: Path) -> str:
    """The study's id on the coach: the folder's name and a random suffix, so a new study in a
    folder of the same name never takes an old study's sessions for its own."""
    import re
    import uuid

    return f"{re.sub(r'[^A-Za-z0-9_]', '_', folder.resolve().name)[:16]}-{uuid.uuid4().hex[:8]}"


def _target_shown(folder: Path) -> Path:
    """The target as participants see it: a BVH in show/ when it has a skeleton."""
    bvh = folder / "show" / "target.bvh"
    return bvh if bvh.exists() else folder / "target.npz"


@study_app.command("init")
def study_init(folder: Path = FOLDER,
               target: Path = typer.Option(..., help="The target motion (a clip file)."),
               participants: int = typer.Option(..., help="How many participants."),
               cases: str = typer.Option("1,2,3,4", help="Cases to run, comma-separated (Table 4.2: 1-4; 6.1: 5, 6; "
                                         "6.4: 7, 8; 'sweep': each participant's alpha sweep of figs. 5.7 / 5.8, "
                                         "alpha 0-2.5 without and with the adverb, cases 10-16 and 30-36)."),
               seed: int = typer.Option(..., help="Seed of the assignment of case orders to participants (log it)."),
               trials: int = typer.Option(4, help="Trials per case (the first shows the target)."),
               emu2: Path | None = typer.Option(None, help="Cases 5, 6: the folder of a study that ran the sweep "
                                                   "with the same participants (their best alphas, `study emu2`), or a "
                                                   "JSON file {participant: [alpha without, alpha with adverb]}."),
               aeu_scale: float | None = typer.Option(None, help="Cases 7, 8: thesis units per our distance unit."),
               aeu1: Path | None = typer.Option(None, help="Case 7 with AEU thresholds fitted from human coaches: "
                                                   "a study folder whose coach seat they answered (e.g. beginners), "
                                                   "or the JSON `study aeu --out` wrote."),
               aeu2: Path | None = typer.Option(None, help="Case 8 likewise (e.g. experienced coaches)."),
               skeleton: Path | None = typer.Option(None, "--skeleton", help=SKELETON_HELP)):
    """Plan a study: counterbalanced, seeded case orders; the target kept in the folder."""
    from shared.reports.study import append, check_new, emu2_from_sweep, expand_cases, plan

    check_new(folder)
    case_list = expand_cases(cases)
    table = None
    if emu2 is not None and emu2.is_dir():
        sweep_plan, sweep_events = _study(emu2)
        table = emu2_from_sweep(sweep_plan, sweep_events)
        if not table:
            fail(f"{emu2}: no participant has finished two alphas of the sweep on both sides (without and with the "
                  "adverb); run it with `--cases sweep`")
        typer.echo(f"EMU-Model 2 from {emu2}'s sweep: " + ", ".join(f"{k} {v[0]:g} / {v[1]:g}" for k, v in table.items()))
    elif emu2 is not None:
        try:
            table = json.loads(emu2.read_text())
        except (OSError, ValueError) as e:
            fail(f"{emu2}: cannot read EMU-Model 2's alphas ({e})")
    fitted = {}
    for case, source in ((7, aeu1), (8, aeu2)):
        if source is not None:
            fit = _aeu_fit(source)
            fitted[case] = fit["thresholds"]
            typer.echo(f"case {case}: AEU thresholds {fit['thresholds'][0]:.1f} / {fit['thresholds'][1]:.1f} from "
                       f"{source}")
    p = plan(participants, case_list, seed, trials, table, aeu_scale, fitted)
    clip = read_clip(target, skeleton=skeleton)
    folder.mkdir(parents=True, exist_ok=True)
    from shared.io import save_clip

    save_clip(clip, folder / "target.npz")
    _save_shown(folder, "target", clip, clip.fps)
    append(folder, {"event": "plan", "plan": {**p, "target": clip.name, "study": _study_id(folder)}})
    typer.echo(f"study in {folder}: {participants} participant(s), cases {case_list}, {trials} trials each")
    for who, order in p["participants"].items():
        typer.echo(f"  {who}: cases {' -> '.join(map(str, order))}")


def _reconcile(c, folder: Path, p: dict, events: list[dict]) -> list[dict]:
    """Trials the coach kept but the log lost (a kill in between) go back into the log."""
    from shared.bus.client import RemoteError
    from shared.reports.study import append, missing_trials, read_log, session_name, trial_event

    for person, order in p["participants"].items():
        for case in order:
            try:
                info = c.request("coach", "state", {"session": session_name(p["study"], person, case)})
            except RemoteError as e:
                if e.code == "not_found":
                    continue
                raise
            for t in missing_trials(events, person, case, info["trials"]):
                append(folder, trial_event(person, case, t, None, recovered=True))
    return read_log(folder)


def _aeu_fit(source: Path, coaches: list[str] | None = None) -> dict:
    """AEU thresholds from a study folder's coach seat, or the JSON `study aeu --out` wrote."""
    from shared.coaching.policies import fit_aeu
    from shared.reports.study import seat_rows

    if source.is_dir():
        rows = seat_rows(_study(source)[1])
        if coaches:
            rows = [r for r in rows if r["coach"] in coaches]
        if not rows:
            fail(f"{source}: no coach-seat answers" + (f" by {', '.join(coaches)}" if coaches else ""))
        return fit_aeu(rows)
    try:
        fit = json.loads(source.read_text())
        t = [float(x) for x in fit["thresholds"]]
    except (OSError, ValueError, KeyError, TypeError) as e:
        fail(f"{source}: not AEU thresholds ({type(e).__name__}: {e}); give a study folder or `study aeu --out`'s file")
    if len(t) != 2 or not 0 <= t[0] <= t[1]:
        fail(f"{source}: AEU thresholds must be two increasing distances, got {t}")
    return {**fit, "thresholds": t}


@study_app.command("aeu")
def study_aeu(folder: Path = FOLDER, coaches: str | None = typer.Option(None, help="Only these coaches "
                                                                           "(comma-separated), e.g. one group."),
              out: Path | None = typer.Option(None, help="Also write the fit as JSON (what `study init --aeu1` reads)."),
              as_json: bool = JSON_OPTION):
    """AEU thresholds fitted from the coach seat's answers (thesis 5.3.3, table 5.2): coaches
    whose adverbs run backwards are left out and named; the two d_p cuts most answers agree with."""
    fit = _aeu_fit(folder, [c.strip() for c in coaches.split(",") if c.strip()] if coaches else None)
    if out is not None:
        out.write_text(json.dumps(fit, indent=1))
    if as_json:
        typer.echo(json.dumps(fit))
        return
    t1, t2 = fit["thresholds"]
    typer.echo(f"AEU thresholds (our d_p units): 'a little more' up to {t1:.1f}, 'more' up to {t2:.1f}, 'much more' "
               f"above; {fit['agreement']:.0%} of {fit['answers']} answers agree (coaches {', '.join(fit['coaches'])})")
    for coach, why in fit["excluded"].items():
        typer.echo(f"  left out {coach}: {why}")


@study_app.command("emu2")
def study_emu2(folder: Path = FOLDER, out: Path | None = typer.Option(None, help="Also write the alphas as JSON "
                                                                      "(what `study init --emu2` reads)."),
               as_json: bool = JSON_OPTION):
    """EMU-Model 2 from a study's alpha sweep (figs. 5.7, 5.8): each participant's alpha whose
    session ended lowest, without and with the adverb, and R_4 at every alpha."""
    from shared.reports.study import SWEEP_CASES, emu2_from_sweep, trials_of

    p, events = _study(folder)
    if not set(SWEEP_CASES) & set(p["cases"]):
        fail(f"{folder} did not plan the sweep (study init --cases sweep)")
    table = emu2_from_sweep(p, events)
    done = trials_of(events)
    if out is not None:
        out.write_text(json.dumps(table, indent=1))
    if as_json:
        typer.echo(json.dumps(table))
        return
    for person in p["participants"]:
        cells = []
        for case, (a, adv) in SWEEP_CASES.items():
            rows = sorted(done.get((person, case), []), key=lambda e: e["trial"])
            if len(rows) == p["trials"]:
                cells.append(f"{a:g}{'+adv' if adv else ''} {rows[-1]['d_p'] / rows[0]['d_p']:.2f}")
        best = table.get(person)
        typer.echo(f"{person}: " + (f"alpha {best[0]:g} without, {best[1]:g} with the adverb" if best else
                                     "not enough of the sweep done") + (f"  (R_{p['trials']}: {', '.join(cells)})"
                                                                        if cells else ""))


@study_app.command("next")
def study_next(folder: Path = FOLDER, participant: str | None = typer.Option(None, help="This participant's next step."),
               as_json: bool = JSON_OPTION):
    """What to do next: who, which case and trial, what to show and say."""
    from shared.reports.study import next_step, trials_of

    p, events = _study(folder)
    with client() as c:
        events = _reconcile(c, folder, p, events)
    step = next_step(p, events, participant)
    if step is None:
        typer.echo(json.dumps({"done": True}) if as_json else "nothing left: every case of every participant is done")
        return
    done = trials_of(events).get((step["participant"], step["case"]), [])
    shown = done[-1].get("shown_next") if done else None
    step.update({"show": shown or str(_target_shown(folder)), "say": done[-1].get("adverb") if done else None})
    if as_json:
        typer.echo(json.dumps(step))
    else:
        typer.echo(f"{step['participant']}, case {step['case']}, trial {step['trial']}: show {step['show']}"
                   + (f' and say "{step["say"]}"' if step["say"] else "") + "; then send the attempt with `study attempt`")


@study_app.command("attempt")
def study_attempt(folder: Path = FOLDER,
                  clips: list[Path] | None = typer.Argument(None, help="The participant's attempt: its repetitions "
                                                                          "(or one continuous --take)."),
                  participant: str = typer.Option(..., help="Whose attempt (the plan's id, e.g. P01)."),
                  take: Path | None = typer.Option(None, "--take", help="One continuous take of the repetitions "
                                                                           "(e.g. from `capture record`): cut "
                                                                           "automatically into them."),
                  expected: int = typer.Option(5, help="Repetitions in the take."),
                  background: list[Path] = typer.Option([], help=BACKGROUND_HELP + " (With --take.)"),
                  say: bool = typer.Option(True, "--say/--no-say", help="Say the adverb aloud into show/*.wav "
                                                                        "(espeak-ng)."),
                  aloud: bool = typer.Option(False, "--aloud", help="Also play it through the speakers (aplay)."),
                  skeleton: Path | None = typer.Option(None, "--skeleton", help=SKELETON_HELP)):
    """One trial of the participant's current case: recorded, and the next motion written to show/
    (with the adverb spoken into a .wav beside it)."""
    from shared.io import load_clip

    if bool(clips) == bool(take):
        fail("give the attempt's repetitions as files, or one continuous --take (not both)")
    if background and take is None:
        fail("--background goes with --take (the other motions its repetitions are told from)")
    if take is not None:
        others = [read_clip(b, skeleton=skeleton) for b in background]
        attempts = _cut(read_clip(take, skeleton=skeleton), load_clip(folder / "target.npz"), expected, others)
    else:
        attempts = [read_clip(x, skeleton=skeleton) for x in clips or []]
    _trial(folder, participant, attempts, say, aloud)


def _start_session(c, folder: Path, p: dict, participant: str, case: int) -> None:
    """The coach's session of a participant's case (its first trial), started afresh."""
    from shared.io import load_clip
    from shared.reports.study import policy, session_name

    c.request("coach", "start", {"session": session_name(p["study"], participant, case),
                                 "target": wire(load_clip(folder / "target.npz")),
                                 "policy": policy(p, participant, case), "replace": True})


def _trial(folder: Path, participant: str, attempts: list, say: bool, aloud: bool = False,
           started: bool = False) -> dict:
    """One trial (the coach scores the attempt and decides the next demonstration and adverb),
    logged; the next demonstration written to show/ and the adverb said beside it. ``started``:
    a first trial's session was started already (while the person performed)."""
    from schemas.common import clip_from_wire
    from shared.reports.study import append, next_step, session_name, trial_event

    p, events = _study(folder)
    with client() as c:
        events = _reconcile(c, folder, p, events)
        step = next_step(p, events, participant)
        if step is None:
            fail(f"{participant} has done every case")
        case, name = step["case"], session_name(p["study"], participant, step["case"])
        if step["trial"] == 1 and not started:
            _start_session(c, folder, p, participant, case)
        r = c.request("coach", "attempt", {"session": name, "clips": [wire(a) for a in attempts]})
    last = step["trial"] == p["trials"]
    shown = None if last else str(_save_shown(folder, f"{participant}_case{case}_trial{step['trial'] + 1}",
                                              clip_from_wire(r["emphatic"]), attempts[0].fps))
    append(folder, trial_event(participant, case, {"number": r["trial"], "d_p": r["d_p"], "alpha_shown": r["alpha_shown"],
                                                   "adverb": r.get("adverb")}, shown))
    typer.echo(f"{participant}, case {case}, trial {step['trial']}: d_p {r['d_p']:.1f}"
               + ("; case done" if last else f"; next: show {shown}" + (f' and say "{r["adverb"]}"' if r.get("adverb") else "")))
    if say and shown is not None and r.get("adverb"):
        from shared.cli.live import say as say_adverb

        say_adverb(r["adverb"], Path(shown).with_suffix(".wav"), aloud)
    return {"participant": participant, "case": case, "trial": step["trial"], "last": last, "shown": shown,
            "adverb": r.get("adverb"), "d_p": r["d_p"]}


def _control(folder: Path, word: str) -> None:
    _study(folder)  # a study's folder, or a clear error
    with open(folder / ".control", "a") as f:
        f.write(word + "\n")
    typer.echo(f"asked the running `study run` in {folder} to {word}")


@study_app.command("redo")
def study_redo(folder: Path = FOLDER):
    """Record the current trial's take again (the running `study run` stops the take it is
    recording, or the one just cut before it is scored, and records anew). Same as typing r."""
    _control(folder, "redo")


@study_app.command("skip")
def study_skip(folder: Path = FOLDER):
    """Leave the current participant's trials for later: the running `study run` moves on to the
    next participant (a later `study run` comes back to them). Same as typing s."""
    _control(folder, "skip")


@study_app.command("quit")
def study_quit(folder: Path = FOLDER):
    """Stop the running `study run` once the trial in progress is done (nothing is lost). Same as
    typing q."""
    _control(folder, "quit")


@study_app.command("run")
def study_run(folder: Path = FOLDER,
              source: str = typer.Option(..., help="The live source the capture service connects to: tcp://HOST:PORT "
                                                   "(a capture suit's BVH stream, or `capture serve`)."),
              participant: str | None = typer.Option(None, help="Only this participant's trials."),
              steps: int | None = typer.Option(None, help="Run this many trials, then stop (default: all)."),
              expected: int = typer.Option(5, help="Repetitions in each take."),
              background: list[Path] = typer.Option([], help=BACKGROUND_HELP),
              space: str | None = typer.Option(None, help=SPACE_HELP),
              label: str | None = typer.Option(None, help=LABEL_HELP),
              idle: float = typer.Option(2.0, help="Seconds without a frame that end a take."),
              seconds: float = typer.Option(120.0, help="A take's longest duration."),
              retries: int = typer.Option(2, help="Takes recorded again when one holds no repetition."),
              check_every: float = typer.Option(0.1, help="Seconds of take between looks for the expected "
                                                           "repetitions (the take ends once they are all seen)."),
              say: bool = typer.Option(True, "--say/--no-say", help="Say the adverb aloud into show/*.wav."),
              aloud: bool = typer.Option(False, "--aloud", help="Also play it through the speakers (aplay).")):
    """The study, live (needs `make up`): trial after trial, the capture service records the take
    from the source until the expected repetitions are seen (or the source stops), cuts it into
    its repetitions; the coach scores them and decides the next demonstration (shown in the
    dashboard and written to show/) and adverb (said into a .wav beside it). Every take is kept in
    takes/; the log, CSV and reports are those of `study attempt`. While it runs, type r (redo the
    take), s (skip to the next participant) or q (quit after this trial) and Enter, or run
    `study redo | skip | quit FOLDER` from another terminal."""
    from schemas.common import clip_from_wire
    from shared.cli.live import Controls, ready_line, save_take, take_and_cut, warm
    from shared.io import load_clip
    from shared.reports.study import next_step

    _study(folder)  # a study's folder, or a clear error
    target_clip = load_clip(folder / "target.npz")
    warm(target_clip)
    target = wire(target_clip)
    others = [wire(read_clip(b)) for b in background]
    named = space_fields(space, label)
    say_if_unguarded(background, space)
    controls = Controls(folder)
    skipped: set[str] = set()
    done = 0
    while steps is None or done < steps:
        p, events = _study(folder)
        with client() as c:
            events = _reconcile(c, folder, p, events)
        who_left = [participant] if participant else [w for w in p["participants"] if w not in skipped]
        step = next((x for w in who_left if (x := next_step(p, events, w)) is not None), None)
        if step is None:
            typer.echo("nothing left: every case of every participant is done" if not skipped else
                       f"nothing left in this run ({', '.join(sorted(skipped))} skipped: `study run` again for them)")
            return
        who, case, n = step["participant"], step["case"], step["trial"]
        typer.echo(f"{who}, case {case}, trial {n}: recording from {source}")
        msg = {"source": source, "seconds": seconds, "idle": idle, "target": target, "expected": expected,
               "check_every": check_every, "background": others, **named}
        with client() as c:
            if n == 1:  # the coach is ready before the person has finished the take
                _start_session(c, folder, p, who, case)
            # named on the capture service with the study's id, as its coach sessions are (session_name): two
            # studies on one cluster (each with a P01) never record over each other's takes
            on_service = f"study-{p['study']}-"
            got = take_and_cut(c, f"{on_service}{who}_case{case}_trial{n}", msg, controls, retries,
                               lambda t: typer.echo(t, err=True))
        if got.get("word") == "skip":
            typer.echo(f"  {who}: skipped on request (their trials are left for a later `study run`)")
            skipped.add(who)
            if participant:
                return
            continue
        if got["result"] is None:
            fail(f"{retries + 1} takes without a repetition of the target: stopped before trial {n} of {who}")
        _trial(folder, who, [clip_from_wire(x) for x in got["result"]["clips"]], say, aloud, started=n == 1)
        line = ready_line(got["info"])
        if line:
            typer.echo(line, err=True)
        with client() as c:  # kept beside the study, after the person has their next demonstration
            # the file keeps its name without the study's id: the folder is the study
            save_take(c, got["name"], folder / "takes" / f"{got['name'].removeprefix(on_service)}.bvh")
        done += 1
        word = controls.next()  # a redo or skip typed now is for the next trial
        if word is not None:
            controls.q.put(word)
        if controls.quit:
            typer.echo("stopped on request (`study run` again to go on)")
            return


def _cut(take, target, expected: int, background: list) -> list:
    """A continuous take cut into the target's repetitions (:mod:`shared.capture.segment`), told
    from the ``background`` motions."""
    from shared.capture.segment import segment

    result = segment(take, target, expected=expected, background=background)
    typer.echo(f"take {take.name}: {result.verdict}", err=True)
    if not result.repetitions:
        fail(f"no repetition of the target in {take.name}: {result.verdict}")
    return result.cut(take)


@study_app.command("seat")
def study_seat(folder: Path = FOLDER, coach: str = typer.Option(..., help="The human coach's id."),
               count: int = typer.Option(12, help="How many learner attempts to judge."),
               seed: int = typer.Option(0, help="Seed of the simulated robot-learners whose attempts are shown."),
               demonstrate: bool = typer.Option(False, "--demonstrate", help="After the adverb, ask for a clip of the "
                                                "coach's own emphatic demonstration (d_s, fig. 5.6, EMU-Model 1).")):
    """Chapter 5's coach seat: watch a learner's attempt next to the target and type the adverb.

    The attempts are simulated learners' (seeded, thesis family, at 1 to 4 trials of progress,
    so d_p varies, as the thesis's robot-learner's did); d_p is measured by the coach service.
    With --demonstrate the coach also records an emphatic demonstration: its distance to the
    target is d_s and its point x_s (eq. 5.2, 5.8)."""
    from schemas.common import clip_from_wire
    from shared.io import load_clip
    from shared.reports.study import ADVERB_CHOICES, append, seat_rows

    p, events = _study(folder)
    if not 1 <= count <= 500:
        fail(f"--count must be 1 to 500, got {count}")
    target = load_clip(folder / "target.npz")
    done = len([r for r in seat_rows(events) if r["coach"] == coach])
    session = f"seat-{p['study']}-{coach}"[:64]
    with client() as c:
        if done == 0:
            c.request("coach", "start", {"session": session, "target": wire(target), "replace": True,
                                         "policy": {"kind": "fixed", "alpha": 0.0, "adverb": None}, "check": False})
        for k in range(done, count):
            learner = f"seat-{coach}-{k}"[:64]
            c.request("simulator", "learner_create", {"learner": learner, "target": wire(target), "index": k,
                                                      "population_seed": seed, "replace": True})
            demo, attempt = wire(target), None
            for _ in range(1 + k % 4):
                attempt = c.request("simulator", "learner_imitate", {"learner": learner, "demonstration": demo})["attempts"]
            c.request("simulator", "delete", {"learner": learner})
            r = c.request("coach", "attempt", {"session": session, "clips": attempt})
            assert attempt is not None  # (imitated at least once)
            shown = _save_shown(folder, f"seat_{coach}_{k + 1}_attempt", clip_from_wire(attempt[0], target.skeleton),
                                target.fps)
            typer.echo(f"attempt {k + 1} of {count}: {shown}  (target: {_target_shown(folder)})")
            while True:
                word = typer.prompt(f"adverb ({' / '.join(ADVERB_CHOICES)})").strip().lower()
                if word in ADVERB_CHOICES:
                    break
                typer.echo(f"  one of: {', '.join(ADVERB_CHOICES)}", err=True)
            extra = _demonstration(c, session, target) if demonstrate else {}
            append(folder, {"event": "seat", "coach": coach, "attempt": k + 1, "d_p": float(r["d_p"]), "adverb": word,
                            "shown": str(shown), **extra})
    typer.echo(f"{coach}: {count} attempts judged")


def _demonstration(c, session: str, target) -> dict:
    """The coach's emphatic demonstration of the attempt just judged: d_s and the three points
    (x_t, x_p, x_s) in one embedding of the seat's space (eq. 5.2, 5.8); blank: none."""
    from shared.coaching.session import attempt_name
    from shared.errors import MirrorcoachError

    while True:
        answer = typer.prompt("file of your emphatic demonstration (blank: none)", default="", show_default=False).strip()
        if not answer:
            return {}
        try:
            demo = read_clip(Path(answer), skeleton=target.skeleton)
            break
        except (MirrorcoachError, OSError) as e:
            typer.echo(f"  cannot read {answer}: {e}", err=True)
    r = c.request("coach", "attempt", {"session": session, "clips": [wire(demo)]})
    info = c.request("pss", "info", {"space": f"coach-{session}"})
    points = {s["name"].split("-")[0]: [float(v) for v in p] for s, p in zip(info["proto_symbols"], info["points"])}
    n = r["trial"]
    return {"d_s": float(r["d_p"]), "x_t": points["target"], "x_p": points[attempt_name(n - 1)],
            "x_s": points[attempt_name(n)], "demonstration": answer}


@study_app.command("export")
def study_export(folder: Path = FOLDER, out: Path = typer.Option(..., help="CSV file for the trials (tidy).")):
    """Every trial as a tidy CSV (the columns of reproduce's tidy.csv) and the seat's answers beside it."""
    import csv

    from shared.reports.study import seat_rows, tidy
    from shared.reproduce.tidy import write

    p, events = _study(folder)
    rows = tidy(events, p["target"])
    write(rows, out)
    seat = seat_rows(events)
    if seat:
        with out.with_name(out.stem + "_seat.csv").open("w", newline="") as f:
            w = csv.DictWriter(f, ("coach", "attempt", "d_p", "adverb"), extrasaction="ignore")
            w.writeheader()
            w.writerows(seat)
    typer.echo(f"wrote {out} ({len(rows)} trials)" + (f" and {out.stem}_seat.csv ({len(seat)} answers)" if seat else ""))


@study_app.command("report")
def study_report(folder: Path = FOLDER, out: Path | None = typer.Option(None, help="Markdown file (default: "
                                                                                      "FOLDER/report.md).")):
    """The thesis's tables from the study's trials (read like the simulated runs') and the seat's Table 5.1."""
    from shared.reports.study import SWEEP_CASES, seat_report, seat_rows, sweep_report, tidy
    from shared.reproduce.coaching_report import case_tables

    p, events = _study(folder)
    rows = tidy(events, p["target"])
    lines = [f"# Study {p['study']}: {len(p['participants'])} participant(s), cases {p['cases']}", "",
             f"{len(rows)} trials logged. Design: {p['design']} (seed {p['seed']}).", "", *case_tables(rows)]
    if set(SWEEP_CASES) & set(p["cases"]):
        lines += sweep_report(p, events, folder)
    seat = seat_rows(events)
    if seat:
        lines += seat_report(seat, folder)
    path = out or folder / "report.md"
    path.write_text("\n".join(lines) + "\n")
    typer.echo(f"wrote {path}")
