"""CLI commands of the coach service: ``coach start | attempt | show | run | list``."""

from __future__ import annotations

import json
import uuid
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
    echo_damaged,
    fail,
    jsonable,
    read_clip,
    say_if_unguarded,
    space_fields,
    wire,
)

coach_app = typer.Typer(help="Coaching sessions with emphatic motions and adverbs (coach service, thesis ch. 4-6).",
                        no_args_is_help=True)
app.add_typer(coach_app, name="coach")


def _target_request(target: str, skeleton: Path | None) -> dict:
    """A clip file, or SPACE:LABEL (a proto-symbol of a pss space)."""
    p = Path(target)
    if not p.exists() and ":" in target:
        space, label = target.split(":", 1)
        return {"target_space": space, "target_label": label}
    return {"target": wire(read_clip(p, skeleton=skeleton))}


def _policy(kind: str, alpha: float, adverb: str, body_part: bool, policy_file: Path | None,
            subgoal: bool = False, effort: bool = False) -> dict:
    if policy_file is not None:
        try:
            d = json.loads(policy_file.read_text())
        except (OSError, ValueError) as e:
            fail(f"{policy_file}: cannot read a policy ({e})")
        d = dict(d.get("policy", d))
        if effort:
            d["effort"] = True
        return d
    if kind in ("aeu1", "aeu2", "emu2", "nb"):
        fail(f"policy {kind} is fitted from data: pass --policy-file (from the coach's policy_fit)")
    if body_part and subgoal:
        fail("give --body-part or --subgoal, not both")
    return {"kind": kind, "alpha": alpha, "adverb": None if adverb == "none" else adverb, "body_part": body_part,
            "subgoal": subgoal, "effort": effort}


SESSION_HELP = "The coaching session (its id, as `coach start` printed it)."
POLICY_HELP = "fixed | emu1 | emu1c (or aeu1, aeu2, emu2, nb with --policy-file)."
ALPHA_HELP = "Emphasis alpha (eq. 4.3)."
ADVERB_HELP = "table (Table 4.1), none, or an adverb."
BODY_PART_HELP = "Emphasise the worst body part only."
POLICY_FILE_HELP = "A fitted policy (JSON)."
EFFORT_HELP = ("Ask the learner how heavy each demonstration felt (1 light .. 4 at its limit) and keep the emphasis "
               "within what its body can give (thesis 6.5.1; chapter 3's interval estimator).")
STRENGTH_HELP = ("The simulated learner's strength: the effort its body can give, in multiples of the target's "
                 "(default: unlimited). Needed for --effort with a simulated learner.")


def _print_trial(r: dict, file: Path | None) -> None:
    adverb = r.get("adverb") or "(no adverb)"
    extra = f"; alpha lowered from {r['alpha']:g}: {r['feasibility']}" if r["alpha_reduced"] else ""
    part = f"; emphasised: {r['part']}" if r.get("part") else ""
    part += f"; towards {r['goal']}" if r.get("goal", "target") != "target" else ""
    part += f"; it will feel it at {r['felt_predicted']:.0%} of its strength" if r.get("felt_predicted") is not None else ""
    typer.echo(f"trial {r['trial']}: d_p {r['d_p']:.1f}, alpha {r['alpha_shown']:g}, \"{adverb}\"{part}{extra}")
    if file is not None:
        typer.echo(f"  next motion to imitate: {file}")


@coach_app.command("start")
def coach_start(target: str = typer.Option(..., help="Target: a clip file, or SPACE:LABEL (a proto-symbol of a space)."),
                learner: str | None = typer.Option(None, help="A simulated learner (created if new)."),
                person: bool = typer.Option(False, "--person", help="A person sends attempts with `coach attempt`."),
                session: str | None = typer.Option(None, help="Session id (default: a new one)."),
                index: int = typer.Option(0, help="Which learner of the seeded population."),
                population_seed: int = typer.Option(0, help="Seed of the learner population."),
                policy: str = typer.Option("fixed", help=POLICY_HELP),
                alpha: float = typer.Option(2.0, help=ALPHA_HELP),
                adverb: str = typer.Option("table", help=ADVERB_HELP),
                body_part: bool = typer.Option(False, "--body-part", help=BODY_PART_HELP),
                subgoal: bool = typer.Option(False, "--subgoal", help="Coach through sub-goals, worst body part first "
                                             "(thesis 4.6, 7.3)."),
                family: str = typer.Option("thesis", help="Simulated learner's family: thesis, error_based, copy, "
                                           "two_rate, fixed_step (shared/agents/learner.py)."),
                effort: bool = typer.Option(False, "--effort", help=EFFORT_HELP),
                strength: float | None = typer.Option(None, min=0.1, max=100.0, help=STRENGTH_HELP),
                policy_file: Path | None = typer.Option(None, help=POLICY_FILE_HELP),
                mode: str = typer.Option("residual", help="residual (emphasis on the real target) or thesis (F_gen(x_s))."),
                skeleton: Path | None = typer.Option(None, "--skeleton", help=SKELETON_HELP),
                as_json: bool = JSON_OPTION):
    """Start a coaching session; prints its id."""
    if person and learner:
        fail("give --learner or --person, not both")
    if not person and not learner:
        fail("give --learner ID (a simulated learner) or --person")
    name = session or f"s{uuid.uuid4().hex[:8]}"
    if strength is not None and not learner:
        fail("--strength is a simulated learner's; a person says how heavy it felt with `coach attempt --felt`")
    req = {"session": name, **_target_request(target, skeleton),
           "policy": _policy(policy, alpha, adverb, body_part, policy_file, subgoal, effort),
           "mode": mode, "index": index, "population_seed": population_seed, "family": family}
    if learner:
        req["learner"] = learner
        if strength is not None:
            req["learner_params"] = {"strength": strength}
    with client() as c:
        r = c.request("coach", "start", req)
    typer.echo(json.dumps(jsonable(r)) if as_json else name)


@coach_app.command("attempt")
def coach_attempt(session: str = typer.Argument(..., help=SESSION_HELP),
                  clips: list[Path] = typer.Argument(..., help="The attempt: its repetitions (5 in the thesis)."),
                  skeleton: Path | None = typer.Option(None, "--skeleton", help=SKELETON_HELP),
                  out: Path = typer.Option(Path("."), help="Folder for the emphatic motion (BVH)."),
                  felt: int | None = typer.Option(None, min=1, max=4, help="How heavy the last motion shown felt: "
                                                     "1 light, 2, 3, 4 at your limit or beyond (sessions started "
                                                     "with --effort)."),
                  as_json: bool = typer.Option(False, "--json", help="alpha, adverb, d_p and the file, as JSON.")):
    """One trial with your own attempt: prints alpha, the adverb and d_p; writes the emphatic motion as BVH."""
    from schemas.common import clip_from_wire
    from shared.io import save_clip

    attempts = [read_clip(p, skeleton=skeleton) for p in clips]
    with client() as c:
        r = c.request("coach", "attempt", {"session": session, "clips": [wire(a) for a in attempts],
                                           **({"felt": felt} if felt is not None else {})})
    # the emphatic motion comes at the space's rate; it is written at the rate the person recorded at
    demo = clip_from_wire(r["emphatic"]).resample(attempts[0].fps)
    out.mkdir(parents=True, exist_ok=True)
    file = out / f"{session}_trial{r['trial']}.bvh"
    if demo.skeleton is not None:
        save_clip(demo, file)
    else:
        file = file.with_suffix(".npz")
        save_clip(demo, file)
    if as_json:
        typer.echo(json.dumps({"alpha": r["alpha_shown"], "adverb": r.get("adverb"), "d_p": r["d_p"], "file": str(file),
                               "trial": r["trial"], "alpha_policy": r["alpha"], "feasibility": r["feasibility"]}))
    else:
        _print_trial(r, file)


def _print_session(info: dict) -> None:
    who = f"learner {info['learner']}" if info.get("learner") else "a person"
    p = info["policy"]
    typer.echo(f"session {info['session']}: target {info['target']}, {who}, policy {p['kind']} (alpha {p['alpha']:g}), "
               f"mode {info['mode']}, {len(info['trials'])} trial(s)")
    import textwrap

    for t, r in zip(info["trials"], info["R"]):
        why = t["feasibility"]
        typer.echo(f"  trial {t['number']}: d_p {t['d_p']:7.1f}  R {r:.3f}  alpha {t['alpha_shown']:<5g} "
                   f"{(t['adverb'] or '-'):<14} {why if len(why) <= 70 else ''}".rstrip())
        if len(why) > 70:  # what was changed and why, whole: under its trial
            typer.echo(textwrap.fill(why, 100, initial_indent="    ", subsequent_indent="    "))


@coach_app.command("show")
def coach_show(session: str = typer.Argument(..., help=SESSION_HELP), as_json: bool = JSON_OPTION):
    """A session's trials: d_p, R, alpha, adverb, feasibility."""
    with client() as c:
        r = c.request("coach", "state", {"session": session})
    typer.echo(json.dumps(jsonable(r))) if as_json else _print_session(r)


@coach_app.command("run")
def coach_run(learner: str = typer.Option(..., help="The simulated learner."),
              trials: int = typer.Option(4, help="Trials to run (the first shows the target)."),
              session: str | None = typer.Option(None, help="Continue this session (default: start one)."),
              target: str | None = typer.Option(None, help="Target for a new session: a clip file or SPACE:LABEL."),
              index: int = typer.Option(0, help="Which learner of the seeded population (new session)."),
              policy: str = typer.Option("fixed", help=POLICY_HELP), alpha: float = typer.Option(2.0, help=ALPHA_HELP),
              adverb: str = typer.Option("table", help=ADVERB_HELP),
              body_part: bool = typer.Option(False, "--body-part", help=BODY_PART_HELP),
              policy_file: Path | None = typer.Option(None, help=POLICY_FILE_HELP),
              subgoal: bool = typer.Option(False, "--subgoal", help="Coach through sub-goals (thesis 4.6, 7.3)."),
              family: str = typer.Option("thesis", help="Learner family: thesis, error_based, two_rate, copy, fixed_step."),
              effort: bool = typer.Option(False, "--effort", help=EFFORT_HELP),
              strength: float | None = typer.Option(None, min=0.1, max=100.0, help=STRENGTH_HELP),
              as_json: bool = JSON_OPTION):
    """Coach a simulated learner for a number of trials (a simulation, not a person)."""
    with client() as c:
        if session is None:
            if target is None:
                fail("a new session needs --target")
            session = f"s{uuid.uuid4().hex[:8]}"
            c.request("coach", "start", {"session": session, **_target_request(target, None), "learner": learner,
                                         "index": index, "family": family,
                                         **({"learner_params": {"strength": strength}} if strength is not None else {}),
                                         "policy": _policy(policy, alpha, adverb, body_part, policy_file, subgoal,
                                                           effort)})
        elif strength is not None or effort:
            fail("--strength and --effort choose a new session's learner and policy; give --target instead of --session")
        r = c.request("coach", "run", {"session": session, "trials": trials}, timeout=60 + 30 * trials)
    if as_json:
        typer.echo(json.dumps(jsonable(r)))
    else:
        _print_session(r)


@coach_app.command("list")
def coach_list():
    """Every coaching session."""
    with client() as c:
        listed = c.request("coach", "list")
    for s in listed["sessions"]:
        typer.echo(f"{s['session']:<24} {s['trials']} trial(s)  {s.get('learner') or 'person'}")
    echo_damaged(listed["damaged"])


@coach_app.command("live")
def coach_live(session: str = typer.Argument(..., help="A session started with `coach start --person` (or a new one: "
                                                       "started here with the default policy)."),
               target: Path = typer.Option(..., help="The session's target motion (its repetitions are cut from each "
                                                     "take)."),
               source: str = typer.Option(..., help="The live source the capture service connects to: tcp://HOST:PORT."),
               trials: int = typer.Option(4, min=1, max=50, help="Trials to run."),
               expected: int = typer.Option(5, min=1, max=50, help="Repetitions in each take."),
               background: list[Path] = typer.Option([], help=BACKGROUND_HELP),
               space: str | None = typer.Option(None, help=SPACE_HELP),
               label: str | None = typer.Option(None, help=LABEL_HELP),
               idle: float = typer.Option(2.0, help="Seconds without a frame that end a take."),
               seconds: float = typer.Option(120.0, help="A take's longest duration."),
               retries: int = typer.Option(2, help="Takes recorded again when one holds no repetition."),
               out: Path | None = typer.Option(None, help="The session's folder: takes, demonstrations and spoken "
                                                             "adverbs (default: ./live-SESSION)."),
               say: bool = typer.Option(True, "--say/--no-say", help="Say the adverb into a .wav beside each "
                                                                     "demonstration."),
               aloud: bool = typer.Option(False, "--aloud", help="Also play it through the speakers (aplay)."),
               skeleton: Path | None = typer.Option(None, "--skeleton", help=SKELETON_HELP)):
    """Coach a person live (needs `make up`): each trial's take is recorded from the source by the
    capture service until the expected repetitions are seen, cut into them and sent to the coach;
    the next demonstration is shown in the dashboard and written to the session's folder, and the
    adverb said into a .wav beside it. Type r (redo the take), s (stop: skip the rest) or q (quit
    after this trial) and Enter while it runs."""
    from schemas.common import clip_from_wire
    from shared.bus.client import RemoteError
    from shared.cli.live import Controls, ready_line, save_take, take_and_cut, warm
    from shared.cli.live import say as say_adverb
    from shared.io import save_clip

    folder = out or Path(f"live-{session}")
    folder.mkdir(parents=True, exist_ok=True)
    tgt = read_clip(target, skeleton=skeleton)
    warm(tgt)
    with client() as c:
        try:
            info = c.request("coach", "state", {"session": session})
        except RemoteError as e:
            if e.code != "not_found":
                raise
            info = c.request("coach", "start", {"session": session, "target": wire(tgt),
                                                "policy": _policy("fixed", 2.0, "table", False, None)})
            typer.echo(f"started session {session} (policy fixed, alpha 2, the adverbs of Table 4.1)", err=True)
    if info.get("learner"):
        fail(f"session {session} coaches the simulated learner {info['learner']}; start one with --person")
    controls = Controls(folder)
    say_if_unguarded(background, space)
    msg = {"source": source, "seconds": seconds, "idle": idle, "target": wire(tgt), "expected": expected,
           "check_every": 0.1, "background": [wire(read_clip(b, skeleton=skeleton)) for b in background],
           **space_fields(space, label)}
    for _ in range(trials):
        trial = len(info.get("trials", [])) + 1
        typer.echo(f"trial {trial}: recording from {source}")
        with client() as c:
            got = take_and_cut(c, f"{session}_trial{trial}", msg, controls, retries, lambda t: typer.echo(t, err=True))
            if got.get("word") == "skip":
                typer.echo("stopped on request (skip)")
                return
            if got["result"] is None:
                fail(f"{retries + 1} takes without a repetition of the target: stopped before trial {trial}")
            clips = [clip_from_wire(x) for x in got["result"]["clips"]]
            r = c.request("coach", "attempt", {"session": session, "clips": [wire(a) for a in clips]})
            demo = clip_from_wire(r["emphatic"]).resample(clips[0].fps)
            file = folder / f"{session}_trial{r['trial'] + 1}.{'bvh' if demo.skeleton is not None else 'npz'}"
            save_clip(demo, file)
            _print_trial(r, file)
            if say and r.get("adverb"):
                say_adverb(r["adverb"], file.with_suffix(".wav"), aloud)
            line = ready_line(got["info"])
            if line:
                typer.echo(line, err=True)
            save_take(c, got["name"], folder / "takes" / f"{got['name']}.bvh")
            info = c.request("coach", "state", {"session": session})
        if controls.quit:
            typer.echo("stopped on request (`coach live` again to go on)")
            return
