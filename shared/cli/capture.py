"""CLI of live capture: ``capture serve | record | segment`` (shared/capture).

A take recorded from a capture suit's live BVH stream (or a clip replayed as one) is cut into
the repetitions of a target, written as files that ``study attempt`` and ``coach attempt`` take:
no one exports and cuts files by hand between trials."""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Optional

import typer

from shared.cli.app import SKELETON_HELP, _fail, app, read_clip

capture_app = typer.Typer(help="Live motion capture: a clip served as a live BVH stream, a take recorded from one, a "
                               "take cut into the repetitions of a target.", no_args_is_help=True)
app.add_typer(capture_app, name="capture")


@capture_app.command("serve")
def capture_serve(clips: list[Path] = typer.Argument(..., help="Clips to play (.amc, .bvh or .npz with a skeleton): "
                                                               "one per connection, in turn."),
                  port: int = typer.Option(7460, help="TCP port to serve on (0: any free port, printed)."),
                  host: str = typer.Option("127.0.0.1", help="Address to bind (loopback by default)."),
                  speed: float = typer.Option(1.0, help="Play this many times faster."),
                  loop: bool = typer.Option(False, "--loop", help="Play again from the start, forever."),
                  header: bool = typer.Option(True, "--header/--no-header",
                                              help="Send the BVH header first (as most suites do)."),
                  skeleton: Optional[Path] = typer.Option(None, help=SKELETON_HELP)):
    """Serve clips as a live BVH stream (the stand-in for a capture suit) until Ctrl-C: each
    connection gets the next clip (a study's takes, one per trial)."""
    from shared.capture.stream import ReplaySource

    cs = [read_clip(c, skeleton=skeleton) for c in clips]
    for path, c in zip(clips, cs):
        if c.skeleton is None:
            _fail(f"{path} has no skeleton: a live BVH stream needs one")
    try:
        src = ReplaySource(cs, host=host, port=port, header=header, speed=speed, loop=loop)
    except OSError as e:
        _fail(f"cannot listen on {host}:{port}: {e.strerror or e}")
    with src:
        typer.echo(f"serving {len(cs)} clip(s) ({', '.join(p.name for p in clips[:3])}"
                   f"{', ...' if len(cs) > 3 else ''}) on {src.address}", err=True)
        typer.echo(src.address)
        try:
            while True:
                time.sleep(0.5)
        except KeyboardInterrupt:
            pass


@capture_app.command("record")
def capture_record(out: Path = typer.Argument(..., help="The take's file (.bvh)."),
                   source: str = typer.Option(..., help="The live source: tcp://HOST:PORT."),
                   seconds: Optional[float] = typer.Option(None, help="Record this long."),
                   frames: Optional[int] = typer.Option(None, help="Record this many frames."),
                   skeleton: Optional[Path] = typer.Option(None, help="A BVH file whose skeleton the stream follows (a "
                                                                       "stream that sends frames without a header)."),
                   idle: float = typer.Option(2.0, help="Seconds without a frame after which the source counts as "
                                                        "stopped."),
                   reconnect: int = typer.Option(0, help="Connect again this many times when the source stops."),
                   as_json: bool = typer.Option(False, "--json", help="Print the take's report as JSON.")):
    """Record a take from a live BVH stream; dropped and missing frames, a source that stops or
    comes back, and a skeleton that changes are reported."""
    from shared.capture.stream import record

    if out.suffix.lower() != ".bvh":
        _fail("a take is written as .bvh")
    take = record(source, out, seconds=seconds, frames=frames, skeleton=skeleton, idle=idle, reconnect=reconnect)
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
                    background: list[Path] = typer.Option([], help="Other motions (clips) a repetition must be nearer "
                                                                    "to the target than; repeat the option."),
                    out: Optional[Path] = typer.Option(None, help="Write each repetition here as rep1.bvh, rep2.bvh, ..."),
                    skeleton: Optional[Path] = typer.Option(None, help=SKELETON_HELP),
                    as_json: bool = typer.Option(False, "--json", help="Print the result as JSON.")):
    """Find the repetitions of a target in one continuous take (each with a confidence), and say
    when the take holds fewer or more than expected, or not the target at all."""
    from shared.capture.segment import segment
    from shared.io import save_clip

    t = read_clip(take, skeleton=skeleton)
    tgt = read_clip(target, skeleton=skeleton)
    bg = [read_clip(b, skeleton=skeleton) for b in background]
    result = segment(t, tgt, expected=expected, background=bg)
    files = []
    if out is not None and result.repetitions:
        out.mkdir(parents=True, exist_ok=True)
        for part in result.cut(t):
            path = out / f"{part.name}.bvh"
            save_clip(part, path)
            files.append(str(path))
    if as_json:
        typer.echo(json.dumps({**result.to_dict(), "files": files}, indent=1))
    else:
        for k, r in enumerate(result.repetitions, 1):
            typer.echo(f"rep {k}: {r.start:.2f}-{r.end:.2f} s, confidence {r.confidence:.2f}"
                       + (f" -> {files[k - 1]}" if files else ""))
        typer.echo(result.verdict)
    if not result.repetitions:
        raise typer.Exit(1)
