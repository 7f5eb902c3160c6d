"""What every command module of the command line shares: the root application and its reading
options, and the helpers that read clips, parse options, fail with one line, and talk to the
cluster. Command modules import this module, never each other; :mod:`shared.cli.app` imports
them (``register``) and adds its own groups. Nothing here imports numpy at import time.
"""

from __future__ import annotations

import sys
from contextlib import contextmanager
from pathlib import Path
from typing import NoReturn

import typer

TIMEOUT_HELP = "Seconds to wait for the service (default: $MIRRORCOACH_TIMEOUT or 120)."

app = typer.Typer(help="mirrorcoach: motion coaching with the Proto-symbol Space method.", no_args_is_help=True,
                  pretty_exceptions_enable=False, add_completion=False)
clip_app = typer.Typer(help="Read, inspect and convert motion clips (ASF/AMC, BVH, NPZ).", no_args_is_help=True)
offline_app = typer.Typer(help="Proto-symbol spaces as local .npz files, without a cluster (library level).",
                          no_args_is_help=True)
app.add_typer(clip_app, name="clip")
app.add_typer(offline_app, name="offline")

#: the ``--json`` and ``--replace`` options of the commands that say nothing more specific (one object each,
#: as a command group's shared arguments are)
JSON_OPTION = typer.Option(False, "--json", help="Print the result as JSON (for scripts) instead of text.")
REPLACE_OPTION = typer.Option(False, "--replace", help="Replace an existing one of that name (default: refuse).")
SKELETON_HELP = "ASF skeleton for AMC files (default: found beside the file or in a sibling asf/ folder)."
BACKGROUND_HELP = ("Other motions (clips) a repetition must be nearer to the target than, so that a person doing "
                   "one of them is not cut into repetitions of the target; repeat the option.")
SPACE_HELP = ("A space of the cluster's pss service (`space build`) holding the target's motion and others: a movement "
              "is a repetition when the space names it the target's motion, instead of the --background check (it "
              "finds more of another performer's repetitions: bench.segmentation); a space holding the target's "
              "motion only once leaves the decision to --background when given.")
LABEL_HELP = "With --space: the target's motion in it (default: the target's own label, else what the space recognises it as)."
POSE_FLOOR_HELP = ("Recognition's variance floor on the pose outputs, for a space that must recognise motions done "
                   "in styles it does not hold (0.03 was chosen on a game studio's styles for a space of several "
                   "performances per motion). Default: 0.05 when most motions have one clip (what recognises other "
                   "styles best there), else none; 0: none. docs/pss.md.")


def pose_floor_for(asked: float | None, labels) -> float | None:
    """The pose floor a space of clips labelled ``labels`` is built with: ``asked`` (0: none), or
    when not asked :func:`shared.pss.symbol.default_pose_floor` (a floor for one clip per motion)."""
    from shared.pss.symbol import default_pose_floor

    if asked is None:
        return default_pose_floor(labels)
    return asked or None


def say_if_never_rejects(info: dict) -> None:
    """Tell the user a space will never answer "none of these" (its summary's ``rejects``, from
    :meth:`shared.pss.space.ProtoSymbolSpace.info`): every motion will get its nearest label."""
    if info.get("rejects") is False:
        typer.echo("note: this space never answers \"none of these\" (too few known motions to calibrate its tests "
                   "on): every motion gets its nearest label, however far; build it from several performances of "
                   "each motion for that")


def say_if_unguarded(background, space) -> None:
    """With neither other motions nor a space, only the target's first cost tells a repetition from
    a different motion that resembles it: said once, on stderr."""
    if not background and not space:
        typer.echo("note: no --background or --space: a movement within the target's first cost counts as a repetition, "
                   "so a different motion close to the target may be cut into repetitions (bench.segmentation: 22 "
                   "stretches of other motions in 8 of its report's sets, none with them); give the other motions the "
                   "person may do", err=True)


def space_fields(space: str | None, label: str | None) -> dict:
    """A capture request's ``space`` and ``label`` fields from the command's options."""
    if label is not None and space is None:
        fail("--label names the target's motion in a --space: give the space too")
    return {**({"space": space} if space else {}), **({"label": label} if label else {})}


#: how this command reads motion files (the root options; docs/files.md)
READING: dict[str, str | None] = {"units": None, "up": None, "translations": None}


@app.callback()
def reading_options(units: str | None = typer.Option(None, "--units", help="Length unit of the motion files: cm, m, mm, "
                                                        "in or cmu (default: read off the body's height, 1-2.2 m)."),
                    up: str | None = typer.Option(None, "--up", help="Up axis of BVH files: y or z (default: from "
                                                     "where the feet are)."),
                    translations: str | None = typer.Option(None, "--translations", help="BVH position channels: "
                                                               "'replace' the joint offset (Blender), 'add' to it, or "
                                                               "'auto' (default: the first frame tells, else Blender).")):
    """mirrorcoach: motion coaching with the Proto-symbol Space method. The options before the
    command say how the motion files it reads are to be read."""
    READING.update(units=units, up=up, translations=translations)


def read_clip(path, skeleton=None, label: str | None = None):
    """:func:`shared.io.load_clip` with the reading options of this command line."""
    from shared.io import load_clip

    return load_clip(path, skeleton=skeleton, label=label, **READING)


def need(module: str, what: str) -> None:
    """Fail with one line before long work when an optional dependency it ends with is missing
    (any other command gets the same line from :func:`shared.cli.app.main` when the import fails)."""
    from shared.extras import missing

    why = missing(module)
    if why is not None:
        fail(f"{what} needs {why}")


def fail(msg: str) -> NoReturn:
    typer.echo(f"error: {msg}", err=True)
    raise typer.Exit(2)


def load_clips(paths: list[Path], skeleton, label: str | None = None):
    from rich.progress import track

    from shared.io import find_clips

    files = find_clips(paths)
    if not files:
        fail("no clip files (.amc, .bvh, .npz) under the given paths")
    clips = [read_clip(f, skeleton=skeleton) for f in track(files, description="reading clips", transient=True,
                                                             disable=not sys.stderr.isatty())]
    if label is not None:
        for c in clips:
            c.label = label
    return clips


def parse_point(point: str):
    import numpy as np

    try:
        x = np.array([float(v) for v in point.split(",")])
    except ValueError:
        fail(f"--point must be comma-separated numbers, got {point!r}")
    if not np.all(np.isfinite(x)):
        fail("--point coordinates must be finite")
    return x


def parse_mix(mix: list[str]) -> dict[str, float]:
    parsed = {}
    for m in mix:
        name, sep, w = m.rpartition("=")
        if not sep or not name:
            fail(f"--mix needs NAME=WEIGHT, got {m!r}")
        try:
            parsed[name] = float(w)
        except ValueError:
            fail(f"--mix needs NAME=WEIGHT, got {m!r}")
    return parsed


def recognition_text(r: dict) -> str:
    """What `space recognize` and `offline recognize` print for a person."""
    if r.get("known", True):
        head = f"{r['label']}   (confidence {r['confidence']:.2f})"
    else:
        why = {"distance": f"it is farther from its nearest class ({r['nearest_label']}) than the space's known "
                           f"motions are from theirs",
               "ratio": f"it is not clearly nearer to {r['nearest_label']} than to the next class",
               "model": "the novelty model finds it between the space's classes"}
        said = [why[t] for t in r.get("rejected_by") or [] if t in why] or [
            f"it is farther from every class of the space than its known motions are (nearest class "
            f"{r['nearest_label']})"]
        head = f"none of these: {'; '.join(said)} (novelty {r['novelty']:.2f} > 1)"
    lines = [head, f"point in the space ({', '.join(f'{v:.3f}' for v in r['point'])})", "nearest proto-symbols:"]
    lines += [f"  {n['distance']:9.3f}  {n['label']:<30} {n['name']}" for n in r["nearest"]]
    if r.get("another_skeleton"):
        lines.append("note: the clip is on another skeleton than the space's: read by where its body's parts are (its "
                     "joints' positions mapped onto the space's), not by its joint angles (docs/pss.md)")
    return "\n".join(lines)


def echo_damaged(damaged: list[dict]) -> None:
    """A list verb's saved files that cannot be read back (shared/io/saved.py), one line each."""
    for d in damaged:
        typer.echo(f"{d['kind']:<8} {d['name']:<24} DAMAGED: {d['message']}")


def client(**kw):
    from shared.bus.client import Client

    return Client(**kw)


def wire(clip, with_skeleton=True) -> dict:
    from schemas.common import clip_to_wire
    from shared.bus.wirefiles import wire_name

    d = clip_to_wire(clip, with_skeleton=with_skeleton)
    d["name"] = wire_name(d["name"])
    if "label" in d:
        d["label"] = wire_name(d["label"])
    return d


@contextmanager
def ctrl_c_ends(message: str):
    """While inside, Ctrl-C sets the yielded event instead of raising KeyboardInterrupt wherever
    the program is (inside a bus request, half-way through writing a file), and says ``message``;
    the caller ends what it is doing at its next look (a take stopped, a file written). A second
    Ctrl-C raises KeyboardInterrupt. Outside the main thread Ctrl-C is left as it is."""
    import os
    import signal
    import threading

    stop = threading.Event()

    def handler(signum, frame):
        if stop.is_set():
            raise KeyboardInterrupt
        stop.set()
        os.write(2, f"Ctrl-C: {message}\n".encode())  # (a print in a handler may meet another print)

    try:
        before = signal.signal(signal.SIGINT, handler)
    except ValueError:  # not the main thread
        before = None
    try:
        yield stop
    finally:
        if before is not None:
            signal.signal(signal.SIGINT, before)


def busy(message: str):
    from rich.console import Console

    return Console(stderr=True).status(message) if sys.stderr.isatty() else _Quiet()


class _Quiet:
    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False


def jsonable(obj):
    if hasattr(obj, "tolist"):  # numpy arrays and scalars (without importing numpy)
        return obj.tolist()
    if isinstance(obj, dict):
        return {k: jsonable(v) for k, v in obj.items() if k != "v"}
    if isinstance(obj, list):
        return [jsonable(v) for v in obj]
    return obj


