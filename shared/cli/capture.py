"""CLI of live capture: ``capture serve | record | segment`` (shared/capture, no cluster needed) and
``capture take | takes | stop | cut`` (the capture service, `make up`).

A take recorded from a capture suit's live BVH stream (or a clip replayed as one) is cut into
the repetitions of a target, written as files that ``study attempt`` and ``coach attempt`` take:
no one exports and cuts files by hand between trials."""

from __future__ import annotations

import json
import time
from pathlib import Path

import typer

from shared.cli.common import (
    BACKGROUND_HELP,
    LABEL_HELP,
    SKELETON_HELP,
    SPACE_HELP,
    app,
    echo_damaged,
    fail,
    read_clip,
    say_if_unguarded,
    space_fields,
)

capture_app = typer.Typer(help="Live motion capture: a clip served as a live BVH stream, a take recorded from one, a "
                               "take cut into the repetitions of a target.", no_args_is_help=True)
app.add_typer(capture_app, name="capture")


@capture_app.command("serve")
def capture_serve(clips: list[Path] = typer.Argument(..., help="Clips to play (.amc, .bvh or .npz with a skeleton): "
                                                               "one per connection, in turn."),
                  port: int = typer.Option(7460, min=0, max=65535, help="TCP port to serve on (0: any free port, printed)."),
                  host: str = typer.Option("127.0.0.1", help="Address to bind (loopback by default)."),
                  speed: float = typer.Option(1.0, help="Play this many times faster."),
                  loop: bool = typer.Option(False, "--loop", help="Play again from the start, forever."),
                  header: bool = typer.Option(True, "--header/--no-header",
                                              help="Send the BVH header first (as most suites do)."),
                  skeleton: Path | None = typer.Option(None, help=SKELETON_HELP),
                  repetitions: int = typer.Option(1, min=1, help="Join this many clips into each take, with rests "
                                                  "between them as a person rests between repetitions (one "
                                                  "performer's clips, in the order given; the last take wraps "
                                                  "round to the first clips): a trial's take without a suit. "
                                                  "Each take's true repetitions are printed on stderr.")):
    """Serve clips as a live BVH stream (the stand-in for a capture suit) until Ctrl-C: each
    connection gets the next clip, or the next take of ``--repetitions`` clips (a study's takes,
    one per trial)."""
    from shared.capture.stream import ReplaySource
    from shared.capture.takes import JoinedTakes

    cs = [read_clip(c, skeleton=skeleton) for c in clips]
    for path, c in zip(clips, cs):
        if c.skeleton is None:
            fail(f"{path} has no skeleton: a live BVH stream needs one")
    takes = cs if repetitions == 1 else JoinedTakes(cs, repetitions)  # (BadInput: said by the CLI's handler)
    try:
        src = ReplaySource(takes, host=host, port=port, header=header, speed=speed, loop=loop)
    except OSError as e:
        fail(f"cannot listen on {host}:{port}: {e.strerror or e}")
    with src:
        typer.echo(f"serving {len(cs)} clip(s) ({', '.join(p.name for p in clips[:3])}"
                   f"{', ...' if len(cs) > 3 else ''})"
                   + (f" as {len(takes)} take(s) of {repetitions} repetitions" if repetitions > 1 else "")
                   + f" on {src.address}", err=True)
        if isinstance(takes, JoinedTakes):
            for k in range(len(takes)):
                take, bounds = takes.joined(k)
                typer.echo(f"  take {k + 1} ({take.duration:.1f} s): "
                           + ", ".join(f"{c.name} {s:.2f}-{e:.2f} s" for c, (s, e) in zip(takes.group(k), bounds)),
                           err=True)
        typer.echo(src.address)
        try:
            while True:
                time.sleep(0.5)
        except KeyboardInterrupt:
            pass


@capture_app.command("record")
def capture_record(out: Path = typer.Argument(..., help="The take's file (.bvh)."),
                   source: str = typer.Option(..., help="The live source: tcp://HOST:PORT."),
                   seconds: float | None = typer.Option(None, help="Record this long."),
                   frames: int | None = typer.Option(None, help="Record this many frames."),
                   skeleton: Path | None = typer.Option(None, help="A BVH file whose skeleton the stream follows (a "
                                                                       "stream that sends frames without a header)."),
                   idle: float = typer.Option(2.0, help="Seconds without a frame after which the source counts as "
                                                        "stopped."),
                   reconnect: int = typer.Option(0, help="Connect again this many times when the source stops."),
                   as_json: bool = typer.Option(False, "--json", help="Print the take's report as JSON.")):
    """Record a take from a live BVH stream; dropped and missing frames, a source that stops or
    comes back, and a skeleton that changes are reported. Ctrl-C ends the take and keeps it
    (a second Ctrl-C gives up on it)."""
    from shared.capture.stream import record
    from shared.cli.common import ctrl_c_ends

    if out.suffix.lower() != ".bvh":
        fail("a take is written as .bvh")
    # the first Ctrl-C ends the take (its frames kept, at the next line or --idle), the second gives it up
    with ctrl_c_ends("ending the take (again to give it up)") as stop:
        take = record(source, out, seconds=seconds, frames=frames, skeleton=skeleton, idle=idle, reconnect=reconnect,
                      stop_when=stop)
    if as_json:
        typer.echo(json.dumps(take.to_dict(), indent=1))
    else:
        for e in take.events:
            typer.echo(f"  {e}", err=True)
        typer.echo(f"{take.frames} frames -> {out} ({take.ended})")
    if not take.frames:
        raise typer.Exit(1)


@capture_app.command("segment")
def capture_segment(take: Path = typer.Argument(..., help="The take: .amc, .bvh or .npz."),
                    target: Path = typer.Option(..., help="The target motion whose repetitions to find."),
                    expected: int = typer.Option(5, help="Repetitions the person was asked for."),
                    background: list[Path] = typer.Option([], help=BACKGROUND_HELP),
                    out: Path | None = typer.Option(None, help="Write each repetition here as rep1.bvh, rep2.bvh, ..."),
                    skeleton: Path | None = typer.Option(None, help=SKELETON_HELP),
                    max_cost: float | None = typer.Option(None, min=0.0, help="How far (as shapes and postures) the "
                                                          "first repetition may be from the target; the default was "
                                                          "chosen so that no other motion is cut (a person far from "
                                                          "the demonstration's way of moving may need more)."),
                    space: Path | None = typer.Option(None, help="A proto-symbol space file (`offline build`) holding "
                                                      "the target's motion and others: a movement is a repetition "
                                                      "when the space names it the target's motion (instead of the "
                                                      "--background check; it finds more of another performer's "
                                                      "repetitions: bench.segmentation; a space holding the target's "
                                                      "motion only once leaves it to --background when given). With "
                                                      "it, --max-cost is the space's first cost (default 1.15)."),
                    label: str | None = typer.Option(None, help=LABEL_HELP),
                    as_json: bool = typer.Option(False, "--json", help="Print the result as JSON.")):
    """Find the repetitions of a target in one continuous take (each with a confidence), and say
    when the take holds fewer or more than expected, or not the target at all (and which test
    every movement failed)."""
    from dataclasses import replace

    from shared.capture.segment import Settings, segment

    space_fields(None if space is None else str(space), label)  # --label needs --space: said before any file is read
    t = read_clip(take, skeleton=skeleton)
    tgt = read_clip(target, skeleton=skeleton)
    bg = [read_clip(b, skeleton=skeleton) for b in background]
    say_if_unguarded(background, space)  # (after the files: a wrong path is said first)
    how = Settings()
    if max_cost is not None:
        how = replace(how, max_cost=max_cost) if space is None else replace(how, space_cost=max_cost)
    sp = None
    if space is not None:
        from shared.pss.space import ProtoSymbolSpace

        sp = ProtoSymbolSpace.load(space)
    result = segment(t, tgt, expected=expected, background=bg, settings=how, space=sp, label=label)
    files = _write_repetitions(out, result.cut(t) if result.repetitions else []) if out is not None else []
    if as_json:
        typer.echo(json.dumps({**result.to_dict(), "files": files}, indent=1))
    else:
        for k, r in enumerate(result.repetitions, 1):
            typer.echo(f"rep {k}: {r.start:.2f}-{r.end:.2f} s, confidence {r.confidence:.2f}"
                       + (f" -> {files[k - 1]}" if files else ""))
        for note in result.notes:
            typer.echo(note)
        typer.echo(result.verdict)
    if not result.repetitions:
        raise typer.Exit(1)


def _write_repetitions(out: Path, parts: list) -> list[str]:
    """Each repetition as ``out/rep<k>.bvh`` (the files, in order). The ``rep<k>.bvh`` of an earlier
    cut into the same folder beyond these are removed, and said so: they were left, and `study
    attempt out/rep*.bvh` took another take's repetitions with this one's."""
    import re

    from shared.io import save_clip

    out.mkdir(parents=True, exist_ok=True)
    files = []
    for k, part in enumerate(parts, 1):
        save_clip(part, out / f"rep{k}.bvh")
        files.append(str(out / f"rep{k}.bvh"))
    earlier = {int(m[1]): f for f in out.glob("rep*.bvh") if (m := re.fullmatch(r"rep(\d+)\.bvh", f.name))}
    stale = [earlier[k] for k in sorted(earlier) if k > len(parts)]
    for f in stale:
        f.unlink(missing_ok=True)
    if stale:
        typer.echo(f"removed {', '.join(f.name for f in stale)} from {out}: an earlier cut's (this take has "
                   f"{len(parts)} repetition(s))", err=True)
    return files


# ---------------------------------------------------------------- the capture service (`make up`)
def _take_line(info: dict) -> str:
    text = f"{info['take']}: {info['state']}, {info['frames']} frames ({info['seconds']:.1f} s) from {info['source']}"
    if info.get("ended"):
        text += f"; {info['ended']}"
    if info.get("error"):
        text += f"; {info['error']}"
    return text


@capture_app.command("take")
def capture_take(name: str = typer.Argument(..., help="The take's name (letters, digits, '_', '.', '-')."),
                 source: str | None = typer.Option(None, help="The live source the service connects to: "
                                                                 "tcp://HOST:PORT (a capture suit, `capture serve`)."),
                 replay: list[Path] = typer.Option([], help="Clips the service plays through a loopback port instead "
                                                            "of a live source (one per connection); repeat the option."),
                 target: Path | None = typer.Option(None, help="With --expected: end the take once that many "
                                                                  "repetitions of this motion are seen."),
                 expected: int | None = typer.Option(None, help="Repetitions that end the take (with --target)."),
                 background: list[Path] = typer.Option([], help=BACKGROUND_HELP + " Kept with the take: `capture cut` "
                                                                "uses them."),
                 seconds: float = typer.Option(120.0, help="The take's longest duration."),
                 idle: float = typer.Option(2.0, help="Seconds without a frame that end the take."),
                 reconnect: int = typer.Option(0, help="Connect again this many times when the source stops."),
                 skeleton: Path | None = typer.Option(None, help="A BVH file whose skeleton the stream follows (a "
                                                                     "stream without a header)."),
                 replace: bool = typer.Option(False, "--replace", help="Record over a finished take of that name."),
                 space: str | None = typer.Option(None, help=SPACE_HELP + " With --target; kept with the take."),
                 label: str | None = typer.Option(None, help=LABEL_HELP),
                 wait: bool = typer.Option(True, "--wait/--no-wait", help="Wait for the take to end, showing its frames."),
                 as_json: bool = typer.Option(False, "--json", help="Print the take's state as JSON.")):
    """Record a take on the capture service (needs `make up`): its frames are published on the bus
    as they arrive (events/capture/frames); dropped or missing frames, a source that stops or
    comes back and a skeleton that changes are in its events. Ctrl-C while waiting ends the take
    (its frames kept)."""
    from shared.cli.common import client, wire

    if (source is None) == (not replay):
        fail("give either --source tcp://HOST:PORT or --replay FILE (one or more)")
    msg: dict = {"take": name, "seconds": seconds, "idle": idle, "reconnect": reconnect, "replace": replace}
    if source is not None:
        msg["source"] = source
    else:
        msg["replay"] = [wire(read_clip(p)) for p in replay]
    if (target is None) != (expected is None):
        fail("--target and --expected go together: the take ends once that many repetitions are seen")
    if target is not None:
        msg["target"], msg["expected"] = wire(read_clip(target)), expected
        msg["background"] = [wire(read_clip(b)) for b in background]
        msg.update(space_fields(space, label))
    elif background or space:
        fail("--background and --space go with --target and --expected (what the target's repetitions are told from)")
    if skeleton is not None:
        try:
            msg["skeleton"] = skeleton.read_text(encoding="latin-1")
        except OSError as e:
            fail(f"{skeleton}: {e.strerror or e}")
    from rich.progress import Progress, SpinnerColumn, TextColumn

    from shared.cli.common import ctrl_c_ends

    # Ctrl-C ends the take (its frames kept), as `capture record`'s does
    with client() as c, ctrl_c_ends("ending the take") as stop:
        info = c.request("capture", "record", msg)
        typer.echo(_take_line(info), err=True)
        if wait:
            deadline = time.monotonic() + seconds + idle * (reconnect + 1) + 60
            with Progress(SpinnerColumn(), TextColumn("{task.description}"), transient=True) as prog:
                task = prog.add_task("recording", total=None)
                while info["state"] == "recording" and time.monotonic() < deadline and not stop.is_set():
                    stop.wait(0.25)
                    info = c.request("capture", "status", {"take": name})
                    prog.update(task, description=f"recording {name}: {info['frames']} frames ({info['seconds']:.1f} s)")
        if info["state"] == "recording" and (wait or stop.is_set()):
            info = c.request("capture", "stop", {"take": name})
    if as_json:
        typer.echo(json.dumps(info, indent=1))
    else:
        for event in info["events"]:
            typer.echo(f"  {event}", err=True)
        typer.echo(_take_line(info))
    if info["state"] == "failed":
        raise typer.Exit(1)


@capture_app.command("takes")
def capture_takes(as_json: bool = typer.Option(False, "--json", help="Print as JSON.")):
    """Every take on the capture service, recording or kept."""
    from shared.cli.common import client

    with client() as c:
        listed = c.request("capture", "list", {})
    takes = listed["takes"]
    if as_json:
        damaged = [{"take": d["name"], "state": "damaged", "damaged": d["message"]} for d in listed["damaged"]]
        typer.echo(json.dumps(takes + damaged, indent=1))
        return
    for t in takes:
        typer.echo(_take_line(t))
    echo_damaged(listed["damaged"])
    if not takes and not listed["damaged"]:
        typer.echo("no takes yet (record one with `mirrorcoach capture take NAME --source ...`)", err=True)


@capture_app.command("stop")
def capture_stop(name: str = typer.Argument(..., help="The take to end (its frames are kept).")):
    """End a take the capture service is recording."""
    from shared.cli.common import client

    with client() as c:
        typer.echo(_take_line(c.request("capture", "stop", {"take": name})))


@capture_app.command("cut")
def capture_cut(name: str = typer.Argument(..., help="A finished take on the capture service."),
                target: Path = typer.Option(..., help="The target motion whose repetitions to find."),
                expected: int = typer.Option(5, help="Repetitions the person was asked for."),
                background: list[Path] = typer.Option([], help=BACKGROUND_HELP + " Without any, those the take "
                                                                "was recorded with."),
                out: Path | None = typer.Option(None, help="Write the take as take.bvh and each repetition as "
                                                              "rep1.bvh, rep2.bvh, ... here."),
                space: str | None = typer.Option(None, help=SPACE_HELP + " Without one, the space the take was "
                                                 "recorded with, if any."),
                label: str | None = typer.Option(None, help=LABEL_HELP),
                as_json: bool = typer.Option(False, "--json", help="Print the result as JSON.")):
    """Find the repetitions of a target in a take the capture service recorded (each with a
    confidence) and, with --out, write the take and the repetitions as files."""
    from schemas.common import clip_from_wire
    from shared.cli.common import client, wire
    from shared.io import save_clip

    msg = {"take": name, "target": wire(read_clip(target)), "expected": expected,
           "background": [wire(read_clip(b)) for b in background], **space_fields(space, label)}
    with client() as c:
        r = c.request("capture", "segment", msg)
        whole = c.request("capture", "clip", {"take": name})["clip"] if out is not None else None
    files = []
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        assert whole is not None  # (asked for with out)
        save_clip(clip_from_wire(whole), out / "take.bvh")
        files = _write_repetitions(out, [clip_from_wire(part) for part in r["clips"]])
    if as_json:
        typer.echo(json.dumps({k: v for k, v in r.items() if k != "clips"} | {"files": files}, indent=1))
    else:
        for k, rep in enumerate(r["repetitions"], 1):
            typer.echo(f"rep {k}: {rep['start']:.2f}-{rep['end']:.2f} s, confidence {rep['confidence']:.2f}"
                       + (f" -> {files[k - 1]}" if files else ""))
        for note in r["notes"]:
            typer.echo(note)
        typer.echo(r["verdict"])
    if not r["repetitions"]:
        raise typer.Exit(1)
