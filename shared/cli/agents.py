"""CLI commands of the simulator service: ``sim perform``, ``other ...`` (a person can take
an other's seat), ``learner ...``."""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path
from typing import Any

import typer

from shared.cli.common import (
    JSON_OPTION,
    READING,
    REPLACE_OPTION,
    SKELETON_HELP,
    app,
    client,
    echo_damaged,
    fail,
    jsonable,
    need,
    read_clip,
    wire,
)

sim_app = typer.Typer(help="MuJoCo bodies on the simulator service (needs `make up`).", no_args_is_help=True)
other_app = typer.Typer(help="Others of chapter 3: simulated agents, or a person answering here.", no_args_is_help=True)
learner_app = typer.Typer(help="Simulated learners of chapters 4-6 (a simulation, not people).", no_args_is_help=True)
app.add_typer(sim_app, name="sim")
app.add_typer(other_app, name="other")
app.add_typer(learner_app, name="learner")

ESTIMATE_HELP = "The estimate (its name, as `estimator start` made it)."


def _body_request(body: str) -> dict:
    """A robot's name, or a skeleton file (ASF/BVH) to build a human body from."""
    p = Path(body)
    if p.suffix.lower() in (".asf", ".bvh"):
        from shared.io import load_skeleton

        if not p.is_file():
            fail(f"{body}: no such skeleton file")
        # read as the motion files are: the root options --units, --up and --translations apply here too
        sk = load_skeleton(p, units=READING["units"]) if p.suffix.lower() == ".asf" else read_clip(p).skeleton
        return {"skeleton": sk.to_json()}
    return {"body": body}


@sim_app.command("perform")
def sim_perform(body: str = typer.Argument(..., help="A robot's name (self, other) or a skeleton file (.asf, .bvh) for a human body."),
                clip: Path = typer.Argument(..., help="The motion (.amc, .bvh, .npz)."),
                out: Path = typer.Option(..., "--out", help="Output .npz: the motion plus tau.<joint> and cog.x|y|z channels."),
                mass: float | None = typer.Option(None, help="Body mass in kg (robots: their own; humans: 70)."),
                skeleton: Path | None = typer.Option(None, "--skeleton", help=SKELETON_HELP),
                track: bool = typer.Option(False, "--track", help="A human body also follows the motion on a simulated "
                                           "floor with a tracking controller: the frames it needs a helping hand in."),
                as_json: bool = typer.Option(False, "--json", help="Print the feasibility report as JSON.")):
    """Perform a motion with a body: joint torques (inverse dynamics), centre of gravity, feasibility."""
    from schemas.common import clip_from_wire
    from shared.io import save_clip

    if out.suffix.lower() != ".npz":
        fail("--out must be a .npz file (BVH and AMC hold motion only; NPZ keeps the torque channels' names)")
    motion = read_clip(clip, skeleton=skeleton)
    req = {**_body_request(body), "clip": wire(motion, with_skeleton=False), "track": track}
    if mass is not None:
        req["mass"] = mass
    with client() as c:
        r = c.request("simulator", "perform", req)
    performed = clip_from_wire(r["clip"], motion.skeleton)  # the file keeps its body: it can become BVH again
    save_clip(performed, out)
    rep = r["report"]
    if as_json:
        typer.echo(json.dumps(jsonable({"file": str(out), "body": r["body"], "report": rep})))
        return
    sensors = performed.group("sensor")
    typer.echo(f"wrote {out}: {performed.n_frames} frames, {len(sensors)} sensor channels "
               f"({sensors[0]} ... {sensors[-1]}) for {r['body']['name']} ({r['body']['mass']:.1f} kg)")
    lim = rep["joint_limit_violations"]
    verdict = {True: "yes", False: "no", None: "not known (nothing could be checked)"}[rep["feasible"]]
    typer.echo(f"feasible: {verdict}; joint limits exceeded on {len(lim)} channel(s)"
               + (f" ({', '.join(list(lim)[:4])})" if lim else "")
               + (f"; centre of gravity outside the support on {rep['support']['frames_outside_support']} frame(s)"
                  if rep["support"].get("checked") else ""))
    s = rep["support"]
    if s.get("tracking_checked"):
        typer.echo(f"tracked on a simulated floor: a helping hand of more than {s['help_limit']:.0%} of the weight needed on "
                   f"{s['frames_tracking_helped']} of {rep['frames']} frame(s) (mean help {s['mean_help']:.0%})")
    for what in rep.get("not_checked", []):
        typer.echo(f"  not checked: {what}")


# ---------------------------------------------------------------------------- others
@other_app.command("create")
def other_create(name: str = typer.Argument(..., help="Name of the other."),
                 person: bool = typer.Option(False, "--person", help="A person answers (with `mirrorcoach other answer`)."),
                 mass: float = typer.Option(4.8, help="Body mass, kg (simulated others)."),
                 rule: str = typer.Option("eq3.8", help="Conversion rule: eq3.8, f1, f2, f3, f4."),
                 d: int = typer.Option(4, help="Density of words: 2, 4, 5, 6, 7 or 8 (5 and 7 are ours; Table 3.1 has 2, 4, 6, 8)."),
                 noise: float = typer.Option(0.0, help="Probability an answer is one bin off."),
                 seed: int = typer.Option(0, help="Seed of the answer noise."),
                 kind: str | None = typer.Option(None, help="Draw an uneven body from the population: "
                                                    "mass, links, payload, shares, damping, friction, joints, legs, mixed; "
                                                    "or one outside the estimators' model: springs, armature, gears, "
                                                    "coupling, stribeck, fatigue, fused (its mass replaces --mass; see "
                                                    "`other reveal`)."),
                 index: int = typer.Option(0, min=0, max=999, help="Which of the kind's population (0-999)."),
                 population_seed: int = typer.Option(2026, help="Seed of the population."),
                 replace: bool = REPLACE_OPTION):
    """Create an other: a simulated agent with hidden parameters, or a person's seat."""
    params: dict[str, Any] = {"d": d} if person else {"mass": mass, "rule": rule, "d": d, "noise": noise, "seed": seed}
    if kind is not None and not person:
        from shared.agents.population import population

        drawn = population(kind, index + 1, seed=population_seed)[index]
        params.update(mass=drawn["mass"], body=drawn["body"], kind=kind, joints=drawn["joints"])
        if drawn.get("transmission"):  # gears, coupling, Stribeck friction, fatigue: between body and feeling
            params["transmission"] = drawn["transmission"]
    with client() as c:
        r = c.request("simulator", "other_create", {"other": name, "kind": "person" if person else "simulated",
                                                    "params": params, "replace": replace})
    typer.echo(f"created other {r['other']} ({r['kind']})")


@other_app.command("ask")
def other_ask(name: str = typer.Argument(..., help="Name of the other."),
              clips: list[Path] = typer.Argument(..., help="One motion (open question) or two (which felt heavier?)."),
              skeleton: Path | None = typer.Option(None, "--skeleton", help=SKELETON_HELP),
              timeout: float = typer.Option(300.0, help="Seconds to wait for a person's answer.")):
    """Ask an other how heavy a motion felt, or which of two motions felt heavier."""
    if len(clips) not in (1, 2):
        fail("give one motion (open question) or two (comparative question)")
    kind = "open" if len(clips) == 1 else "compare"
    text = "How heavy did that feel?" if kind == "open" else "Which felt heavier, the first or the second?"
    req = {"other": name, "kind": kind, "text": text, "timeout": timeout,
           "clips": [wire(read_clip(p, skeleton=skeleton)) for p in clips]}
    with client() as c:
        r = c.request("simulator", "other_ask", req, timeout=timeout + 30)
    typer.echo(r["answer"])


@other_app.command("answer")
def other_answer(name: str | None = typer.Argument(None, help="Only this other's questions (default: all)."),
                 folder: Path = typer.Option(Path("questions"), help="Where the motions are written (BVH, or NPZ for robot joint angles)."),
                 wait: float = typer.Option(0.0, help="Seconds to wait for the first question if none is pending."),
                 follow: bool = typer.Option(False, "--follow", help="Keep waiting for more questions (up to --wait after each)."),
                 answer: str | None = typer.Option(None, help="Answer without a prompt (for scripts)."),
                 max_questions: int = typer.Option(100, help="Stop after this many questions.")):
    """Take an other's seat: see each pending question and its motion(s) as files, type the answer."""
    from schemas.common import clip_from_wire
    from shared.io import save_clip

    deadline = time.monotonic() + max(wait, 0.0)
    answered = 0
    with client() as c:
        while answered < max_questions:
            qs = c.request("simulator", "other_pending", {"other": name} if name else {}, timeout=30)["questions"]
            if not qs:
                if time.monotonic() >= deadline or (answered and not follow):
                    break
                time.sleep(0.5)
                continue
            q = qs[0]
            folder.mkdir(parents=True, exist_ok=True)
            paths = []
            for i, w in enumerate(q["clips"], 1):
                motion = clip_from_wire(w)
                # BVH where the motion has a skeleton to draw; a robot's joint angles go to NPZ
                p = folder / f"{q['question']}_{i}.{'bvh' if motion.skeleton is not None else 'npz'}"
                save_clip(motion, p)
                paths.append(p)
            typer.echo(f"[{q['other']}] {q['text'] or ('How heavy did that feel?' if q['kind'] == 'open' else 'Which felt heavier?')}")
            for p in paths:
                typer.echo(f"  motion: {p}")
            typer.echo(f"  answers: {', '.join(q['accepted'])}")
            while True:
                given = answer if answer is not None else typer.prompt("answer")
                try:
                    r = c.request("simulator", "other_answer", {"question": q["question"], "answer": given}, timeout=30)
                    typer.echo(f"  sent: {r['answer']}")
                    deadline = time.monotonic() + max(wait, 0.0)
                    break
                except Exception as e:  # an answer outside the accepted words: say so and ask again
                    if answer is not None or not sys.stdin.isatty() or getattr(e, "code", "") != "bad_request":
                        raise
                    typer.echo(f"  {getattr(e, 'message', e)}")
            answered += 1
    typer.echo(f"answered {answered} question(s)" if answered else "no pending questions")


@other_app.command("reveal")
def other_reveal(name: str = typer.Argument(..., help="The simulated other.")):
    """Show an other's hidden parameters (for evaluation; the estimator never asks this)."""
    with client() as c:
        typer.echo(json.dumps(jsonable(c.request("simulator", "other_reveal", {"other": name}))))


def _print_list(service: str, as_json: bool, lines, empty: str) -> None:
    """A service's ``list`` reply: as JSON, or its ``lines(reply)`` and any file that cannot be read
    back, or ``empty`` when there is neither."""
    with client() as c:
        r = c.request(service, "list")
    if as_json:
        typer.echo(json.dumps(jsonable(r)))
        return
    text = lines(r)
    for line in text:
        typer.echo(line)
    echo_damaged(r["damaged"])
    if not text and not r["damaged"]:
        typer.echo(empty)


@app.command("agents")
def agents_list(as_json: bool = JSON_OPTION):
    """Every other and learner on the simulator."""
    _print_list("simulator", as_json, lambda r: [f"other    {o['other']:<24} {o['kind']}" for o in r["others"]] +
                [f"learner  {lr['learner']:<24} {lr['trials']} trial(s)" for lr in r["learners"]], "no agents")


# ---------------------------------------------------------------------------- learners
@learner_app.command("create")
def learner_create(name: str = typer.Argument(..., help="A name for the new learner."), target: Path = typer.Argument(..., help="The target motion."),
                   population_seed: int = typer.Option(0, help="Which seeded population."),
                   index: int = typer.Option(0, help="Which learner of the population."),
                   skeleton: Path | None = typer.Option(None, "--skeleton", help=SKELETON_HELP),
                   replace: bool = REPLACE_OPTION):
    """Create a simulated learner of a target motion."""
    with client() as c:
        r = c.request("simulator", "learner_create", {"learner": name, "target": wire(read_clip(target, skeleton=skeleton)),
                                                      "population_seed": population_seed, "index": index,
                                                      "replace": replace})
    typer.echo(f"created learner {r['learner']} ({len(r['channels'])} channels)")


@learner_app.command("imitate")
def learner_imitate(name: str = typer.Argument(..., help="The simulated learner."), demonstration: Path = typer.Argument(..., help="The motion shown."),
                    adverb: str | None = typer.Option(None, help="a little more | more | much more | more like this"),
                    out: Path = typer.Option(Path("."), help="Folder for the 5 attempts (BVH)."),
                    skeleton: Path | None = typer.Option(None, "--skeleton", help=SKELETON_HELP)):
    """Show a learner a motion; write its next attempt (5 repetitions) as BVH."""
    from schemas.common import clip_from_wire
    from shared.io import save_clip

    demo = read_clip(demonstration, skeleton=skeleton)
    req = {"learner": name, "demonstration": wire(demo)}
    if adverb:
        req["adverb"] = adverb
    with client() as c:
        r = c.request("simulator", "learner_imitate", req)
    out.mkdir(parents=True, exist_ok=True)
    for a in r["attempts"]:
        clip = clip_from_wire(a, demo.skeleton)
        save_clip(clip, out / f"{clip.name}.bvh")
    typer.echo(f"trial {r['trial']}: wrote {len(r['attempts'])} attempts to {out}")


@learner_app.command("delete")
def learner_delete(name: str = typer.Argument(..., help="The simulated learner.")):
    """Delete a simulated learner (a coaching session's learner goes with `coach delete`)."""
    with client() as c:
        c.request("simulator", "delete", {"learner": name})
    typer.echo(f"deleted learner {name}")


# ---------------------------------------------------------------------------- dialogue and estimator
dialogue_app = typer.Typer(help="Questions to others and their transcripts (dialogue service).", no_args_is_help=True)
estimator_app = typer.Typer(help="Estimating what an other feels (estimator service, thesis ch. 3).", no_args_is_help=True)
app.add_typer(dialogue_app, name="dialogue")
app.add_typer(estimator_app, name="estimator")


@dialogue_app.command("transcript")
def dialogue_transcript(dialogue: str = typer.Argument(..., help="Dialogue id (an estimate's name)."),
                        as_json: bool = JSON_OPTION):
    """Every question and answer of a dialogue, in order."""
    with client() as c:
        r = c.request("dialogue", "transcript", {"dialogue": dialogue})
    if as_json:
        typer.echo(json.dumps(jsonable(r)))
        return
    for line in r["lines"]:
        stamp = time.strftime("%H:%M:%S", time.localtime(line["t"]))
        extra = f"  (k = {line['k']})" if line.get("k") else (f"  ({line['answer']})" if line.get("answer") else "")
        flag = "  [not understood]" if line.get("understood") is False else ""
        typer.echo(f"{stamp}  {line['speaker']:>10}: {line['text']}{extra}{flag}")


@dialogue_app.command("list")
def dialogue_list():
    """Every dialogue and its length."""
    with client() as c:
        for d in c.request("dialogue", "list")["dialogues"]:
            typer.echo(f"{d['dialogue']:<24} {d['lines']} lines")


def _print_estimate(info: dict) -> None:
    hi = info.get("scale_high")
    lang = info["language"]
    typer.echo(f"estimate {info['estimate']} of {info['other']}: {info['sets_done']} set(s), d = {lang['d']}, rule "
               f"{lang['rule']}; torque scale {info['scale']:.3f} (answers allow {info['scale_low']:.3f} .. "
               f"{'inf' if hi is None else f'{hi:.3f}'}{'' if info['consistent'] else ', CONTRADICTORY'})")
    if info.get("body"):
        b = info["body"]
        parts = [f"{c} {t:.3g}" for c, t in zip(b["columns"], b["theta"]) if abs(t) > 1e-6]
        typer.echo(f"  body estimate from {b['answers']} answer(s): {', '.join(parts)}")
    for n in info["notes"][-3:]:
        typer.echo(f"  note: {n}")


@estimator_app.command("start")
def estimator_start(name: str = typer.Argument(..., help="Estimate id."), other: str = typer.Argument(..., help="The other."),
                    d: int = typer.Option(4, help="Density of the words: 2, 4, 6, 8."),
                    g_max: float = typer.Option(0.6, help="Top of the g range the words split (shared language)."),
                    knee: bool = typer.Option(False, "--knee", help="Also the right knee (needed to identify rules)."),
                    missing: list[str] = typer.Option([], "--missing", help="A joint the other lacks (seen when it "
                                                      "imitates); the self holds it still. Repeatable."),
                    probes: int = typer.Option(4, help="Probe motions per conversation set (0: the thesis's sets only)."),
                    replace: bool = REPLACE_OPTION):
    """Start estimating an other from the self's own experience (step 1)."""
    joints = [j for j in ["shoulder_pitch", "shoulder_roll", "elbow"] + (["knee"] if knee else []) if j not in missing]
    with client() as c:
        _print_estimate(c.request("estimator", "start", {"estimate": name, "other": other, "d": d, "g_max": g_max,
                                                         "joints": joints, "missing": missing, "probes": probes,
                                                         "replace": replace}))


@estimator_app.command("converse")
def estimator_converse(name: str = typer.Argument(..., help=ESTIMATE_HELP), sets: int = typer.Option(3, help="Conversation sets to run."),
                       timeout: float = typer.Option(120.0, help="Seconds to wait for each answer.")):
    """Run conversation sets with the other (eq. 3.2-3.6)."""
    with client() as c:
        r = c.request("estimator", "converse", {"estimate": name, "sets": sets, "timeout": timeout},
                      timeout=sets * 20 * (timeout + 10))
    _print_estimate(r["info"])
    if r.get("model"):
        typer.echo(f"model check: {r['model']['verdict']}")
    if r.get("stopped"):
        typer.echo(f"stopped: {r['stopped']}")


@estimator_app.command("estimate")
def estimator_estimate(name: str = typer.Argument(..., help=ESTIMATE_HELP), clip: Path = typer.Argument(..., help="A motion of the robot's joints."),
                       method: str = typer.Option("body", help="body (the estimated body), interval (one "
                                                  "torque scale) or thesis (eq. 3.5)."),
                       out: Path | None = typer.Option(None, help="Write the motion with the estimated torques (.npz).")):
    """How heavy the other would feel a motion, and its estimated torques."""
    from schemas.common import clip_from_wire
    from shared.io import save_clip

    with client() as c:
        r = c.request("estimator", "estimate", {"estimate": name, "clip": wire(read_clip(clip)), "method": method})
    typer.echo(f"{r['word']} (k = {r['k']}, g = {r['g']:.4f}, {method})")
    if out is not None:
        save_clip(clip_from_wire(r["clip"]), out)
        typer.echo(f"wrote {out}")


@estimator_app.command("identify")
def estimator_identify(name: str = typer.Argument(..., help=ESTIMATE_HELP),
                       candidates: str = typer.Option("thesis", help="thesis (f1-f4) or weighted (12 rules)."),
                       method: str = typer.Option("auto", help="auto (pairs chosen on the estimated body, answers weighed "
                                                  "against noise) or thesis (m1/m2, m3/m4).")):
    """Identify the other's conversion rule by comparative questions (thesis 3.4)."""
    with client() as c:
        r = c.request("estimator", "identify_rule", {"estimate": name, "candidates": candidates, "method": method})
    for q in r["questions"]:
        typer.echo(f"  asked {q['pair']}: {q['answer']}")
    typer.echo(f"rule: {r.get('rule') or 'not identified'} ({r['reason']})")
    if r.get("posterior"):
        typer.echo("posterior: " + ", ".join(f"{k} {v:.1%}" for k, v in sorted(r["posterior"].items(), key=lambda x: -x[1])))


@estimator_app.command("info")
def estimator_info(name: str = typer.Argument(..., help=ESTIMATE_HELP), as_json: bool = JSON_OPTION):
    """An estimate's state."""
    with client() as c:
        r = c.request("estimator", "info", {"estimate": name})
    typer.echo(json.dumps(jsonable(r))) if as_json else _print_estimate(r)


@estimator_app.command("list")
def estimator_list(as_json: bool = JSON_OPTION):
    """Every estimate: its other and the conversation sets done (and any whose file cannot be read back)."""
    _print_list("estimator", as_json,
                lambda r: [f"{e['estimate']:<24} of {e['other'] or '?'}: {e['sets_done']} set(s)" for e in r["estimates"]],
                "no estimates (start one with `mirrorcoach estimator start NAME OTHER`)")


@app.command("reproduce")
def reproduce(chapters: list[str] = typer.Argument(..., help="Which chapters: ch3 (more arrive with the coach)."),
              out: Path = typer.Option(Path("reports"), help="Folder for the reports and plots (one sub-folder per chapter)."),
              sets: int = typer.Option(6, help="Conversation sets per curve (ch3)."),
              others: int = typer.Option(10, help="Simulated others per kind of body (ch3)."),
              kinds: str = typer.Option("all", help="Kinds of body for ch3, comma-separated: mass, links, payload, "
                                        "shares, damping, friction, joints, legs, mixed (default all)."),
              outside: bool = typer.Option(True, "--outside/--no-outside", help="Also others outside the estimators' "
                                           "model, reported apart and never tuned on (ch3): springs, armature, gears, "
                                           "coupling, stribeck, fatigue."),
              learners: int = typer.Option(12, help="Simulated learners per experiment group (ch4-6)."),
              hdm05: Path | None = typer.Option(None, help="HDM05 data (ch4-6 targets; default $MIRRORCOACH_HDM05 or ../shared/data/hdm05)."),
              targets: str = typer.Option("squat,throw", help="Targets for ch4-6: squat, throw."),
              families: str = typer.Option("all", help="Learner families for ch4-6, comma-separated: thesis, "
                                           "error_based, two_rate, copy, fixed_step (default all)."),
              sensitivity_learners: int = typer.Option(8, help="Learners per setting of each family's sensitivity "
                                                       "sweep (ch4-6; 0 skips it).")):
    """Rerun the thesis's experiments on the cluster (simulated agents) and write reports with plots."""
    from shared.bus.client import Client

    need("matplotlib", "reproduce (its plots at the end of the run)")
    from shared.bus.cluster import down, running, up
    from shared.bus.config import Settings

    known = {"ch3", "ch4", "ch5", "ch6"}
    unknown = [c for c in chapters if c not in known]
    if unknown:
        fail(f"unknown chapter(s) {', '.join(unknown)}; available: {', '.join(sorted(known))}")
    settings = Settings()
    started = False
    if not running(settings):
        if up(settings, echo=typer.echo) != 0:
            raise typer.Exit(1)
        started = True
    import signal

    def stop(signum, frame):  # `kill`, `timeout`, a cancelled job: stopped as by Ctrl-C (a cluster it started goes down)
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGTERM, stop)
    try:
        with Client(settings) as c:
            if "ch3" in chapters:
                from shared.agents.population import KINDS
                from shared.reproduce.ch3 import run

                chosen_kinds = list(KINDS) if kinds == "all" else [k.strip() for k in kinds.split(",") if k.strip()]
                bad = [k for k in chosen_kinds if k not in KINDS]
                if bad or not chosen_kinds:
                    fail(f"unknown kind(s) {bad}; choose from {', '.join(KINDS)}")
                if not 1 <= others <= 1000:
                    fail(f"--others must be 1 to 1000, got {others}")
                run(c, out / "ch3", sets=sets, echo=typer.echo, others=others, kinds=chosen_kinds, outside=outside)
            if {"ch4", "ch5", "ch6"} & set(chapters):
                import os

                from shared.reproduce.coaching import run as run_coaching
                from shared.reproduce.coaching_stats import TARGETS

                data = hdm05 or Path(os.environ.get("MIRRORCOACH_HDM05") or Path(__file__).resolve().parents[2].parent / "shared" / "data" / "hdm05")
                chosen = [t.strip() for t in targets.split(",") if t.strip()]
                bad = [t for t in chosen if t not in TARGETS]
                if bad or not chosen:
                    fail(f"unknown target(s) {bad}; choose from {', '.join(TARGETS)}")
                if not (data / "amc").is_dir():
                    fail(f"HDM05 data not found at {data} (give --hdm05 or set MIRRORCOACH_HDM05)")
                from shared.agents.learner import FAMILIES

                fams = list(FAMILIES) if families == "all" else [f.strip() for f in families.split(",") if f.strip()]
                bad = [f for f in fams if f not in FAMILIES]
                if bad or not fams:
                    fail(f"unknown learner famil(ies) {bad}; choose from {', '.join(FAMILIES)}")
                if not 2 <= learners <= 1000 or not 0 <= sensitivity_learners <= 1000:
                    fail("--learners must be 2 to 1000 and --sensitivity-learners 0 to 1000 (statistics need two)")
                run_coaching(c, data, out / "ch4-6", learners=learners, targets=chosen, families=fams,
                             sensitivity_learners=sensitivity_learners, echo=typer.echo)
    except KeyboardInterrupt:  # (shared/reproduce/stopping.py: within a request of Ctrl-C)
        typer.echo("interrupted: a chapter's report is written once all its sections are done; "
                   "the chapters written before it are kept", err=True)
        raise typer.Exit(130) from None
    finally:
        signal.signal(signal.SIGTERM, previous)
        if started:
            down(settings, echo=typer.echo)
