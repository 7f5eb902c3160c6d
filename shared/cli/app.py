"""The ``mirrorcoach`` command line.

``clip`` works on files; ``offline`` works on space files without a cluster (library level);
``space``, ``status``, ``up``, ``down`` and ``schemas`` talk to the running cluster
(``shared/cli/cluster.py``). Every error the user can act on is one line on stderr and exit
code 2, never a traceback.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import typer

from shared.cli.common import (
    JSON_OPTION,
    POSE_FLOOR_HELP,
    SKELETON_HELP,
    app,
    clip_app,
    fail,
    load_clips,
    offline_app,
    parse_mix,
    parse_point,
    pose_floor_for,
    read_clip,
    recognition_text,
    say_if_never_rejects,
)
from shared.errors import MirrorcoachError


@clip_app.command("info")
def clip_info(file: Path = typer.Argument(..., help="Clip file: .amc, .bvh or .npz."),
              skeleton: Path | None = typer.Option(None, "--skeleton", help=SKELETON_HELP),
              as_json: bool = typer.Option(False, "--json", help="Machine-readable output.")):
    """Frames, frame rate, duration, skeleton and channel groups of a clip."""
    import numpy as np

    c = read_clip(file, skeleton=skeleton)
    info = {
        "file": str(file), "name": c.name, "label": c.label, "frames": c.n_frames, "fps": c.fps,
        "duration_s": round(c.duration, 4), "channels": len(c.channels),
        "groups": {g: len(v) for g, v in c.groups.items()},
        "skeleton": None if c.skeleton is None else {"name": c.skeleton.name, "joints": len(c.skeleton.joints),
                                                     "format": c.skeleton.source_format,
                                                     "unit_m": c.skeleton.unit_m,
                                                     "height_m": round(c.skeleton.rest_height(), 4)},
        "read_as": c.read_as,
        "range_deg": [float(np.min(c.data)), float(np.max(c.data))] if c.data.size else None,
    }
    if as_json:
        typer.echo(json.dumps(info))
        return
    typer.echo(f"{c.name}  ({file})")
    typer.echo(f"  label     {c.label}")
    typer.echo(f"  frames    {c.n_frames} at {c.fps:g} fps ({c.duration:.2f} s)")
    typer.echo(f"  channels  {len(c.channels)}: " + ", ".join(f"{g} {n}" for g, n in info["groups"].items()))
    if c.skeleton is not None:
        typer.echo(f"  skeleton  {c.skeleton.name} ({len(c.skeleton.joints)} joints, {c.skeleton.source_format}, "
                   f"1 unit = {c.skeleton.unit_m:.4g} m, {c.skeleton.rest_height():.2f} m tall at rest)")
    if c.read_as:
        typer.echo("  read as   " + ", ".join(f"{k} {', '.join(v) if isinstance(v, list) else v}" for k, v in c.read_as.items()))


@clip_app.command("convert")
def clip_convert(src: Path = typer.Argument(..., help="Input clip: .amc, .bvh or .npz."),
                 dst: Path = typer.Argument(..., help="Output clip: .bvh, .npz or .amc (chosen by extension)."),
                 skeleton: Path | None = typer.Option(None, "--skeleton", help=SKELETON_HELP),
                 fps: float | None = typer.Option(None, "--fps", help="Resample to this frame rate first.")):
    """Convert a clip between AMC, BVH and NPZ (BVH holds motion only; NPZ keeps everything)."""
    from shared.io import save_clip

    c = read_clip(src, skeleton=skeleton)
    if fps is not None:
        c = c.resample(fps)
    if dst.exists() and dst.resolve() == src.resolve():
        fail("output would overwrite the input")
    save_clip(c, dst)
    typer.echo(f"wrote {dst} ({c.n_frames} frames at {c.fps:g} fps)")


#: MB of clip files that ``offline build`` holds in memory at once (together); more are read when needed
HOLD_CLIP_MB = 256.0


@offline_app.command("build")
def space_build(out: Path = typer.Argument(..., help="Space file to write (.npz)."),
                paths: list[Path] = typer.Argument(..., help="Clip files or folders; label = the clip's parent folder."),
                dim: int = typer.Option(3, help="Dimension of the space."),
                states: int | None = typer.Option(None, help="HMM states (default: from the shortest clip, at most 15)."),
                group_by: str = typer.Option("clip", help="'clip': a proto-symbol per clip; 'label': one per label."),
                pose_floor: float | None = typer.Option(None, "--pose-floor", min=0.0, help=POSE_FLOOR_HELP),
                skeleton: Path | None = typer.Option(None, "--skeleton", help=SKELETON_HELP),
                hold_mb: float = typer.Option(HOLD_CLIP_MB, "--hold-mb", min=0,
                                              help="Clip files held in memory at once, MB together; above it each "
                                                   "file is read twice (statistics, then its HMM) instead of held.")):
    """Build a Proto-symbol Space from clips (eq. 2.5) and save it. Clips whose files add up to
    more than --hold-mb are not held in memory, so thousands of clips build in the memory of
    their HMMs."""
    from rich.progress import Progress

    from shared.io import LazyClips, find_clips
    from shared.pss.space import ProtoSymbolSpace

    files = find_clips(paths)
    lazy = sum(f.stat().st_size for f in files) > hold_mb * 2**20
    clips = None if lazy else load_clips(files, skeleton)
    with Progress(transient=True, disable=not sys.stderr.isatty()) as prog:
        if lazy:
            reading = prog.add_task("reading clips (statistics, then one HMM at a time)", total=2 * len(files))
            clips = LazyClips(files, read=lambda f: read_clip(f, skeleton=skeleton),
                              on_read=lambda _: prog.advance(reading))
        assert clips is not None  # (read, or to be read one at a time)
        task = prog.add_task("training proto-symbols", total=len(clips))
        space = ProtoSymbolSpace.build(clips, dim=dim, n_states=states, group_by=group_by, name=out.stem,
                                       pose_floor=pose_floor or None,
                                       progress=lambda done, total: prog.update(task, completed=done, total=total))
    if pose_floor is None:  # the default for the labels of the clips as read (an NPZ clip carries its own)
        floor = pose_floor_for(None, [s.label for s in space.symbols for _ in s.clips])
        space = space if floor is None else space.with_pose_floor(floor)
    space.save(out)
    i = space.info()
    typer.echo(f"wrote {out}: {i['n_proto_symbols']} proto-symbols, {len(i['labels'])} labels, "
               f"{space.params.n_states} states, stress-1 {i['stress1']:.3f}")
    say_if_never_rejects(i)


@offline_app.command("recognize")
def space_recognize(space_file: Path = typer.Argument(..., help="Space file."),
                    clips: list[Path] = typer.Argument(..., help="Clip(s): several are repetitions of one motion."),
                    as_json: bool = JSON_OPTION,
                    skeleton: Path | None = typer.Option(None, "--skeleton", help=SKELETON_HELP)):
    """Recognise a motion: its class with a calibrated confidence (or "none of these"), its
    nearest proto-symbols and its point in the space (eq. 2.6). How the label is decided:
    docs/pss.md, "How a motion is recognised"."""
    from shared.cli import lasting_imports

    with lasting_imports():
        from shared.compiled import use_numba

        use_numba(False)  # one clip's work is milliseconds: numba's start-up (~0.6 s) would be most of the command
        import shared.io  # noqa: F401  (read_clip's)
        from shared.pss.recognition import rejected_by
        from shared.pss.space import ProtoSymbolSpace

    space = ProtoSymbolSpace.load(space_file)
    reps = [read_clip(c, skeleton=skeleton) for c in clips]
    r = space.recognize(reps)

    out = {**({"label": r.label} if r.label is not None else {}), "known": r.label is not None,
           **({"rejected_by": rejected_by(r.decision)} if r.label is None and r.decision is not None else {}),
           "nearest_label": r.nearest_label, "confidence": r.confidence, "novelty": r.novelty,
           "point": [float(v) for v in r.point],
           "nearest": [{"name": n, "label": lab, "distance": d} for n, lab, d in r.nearest], "stress": r.stress,
           **({"another_skeleton": True} if r.another_skeleton else {})}
    typer.echo(json.dumps(out) if as_json else recognition_text(out))


evaluate_app = typer.Typer(help="Measured reports: how well mirrorcoach does next to its peers.", no_args_is_help=True)
app.add_typer(evaluate_app, name="evaluate")


@evaluate_app.command("recognition")
def evaluate_recognition(data: Path = typer.Option(Path("../shared/data/hdm05"), "--data",
                                                   help="Folder of labelled clips of several performers (HDM05 layout: "
                                                        "amc/<class>/*.amc with asf/ beside)."),
                         out: Path = typer.Option(Path("reports/recognition"), "--out", help="Folder for report.md and results.json."),
                         peers: bool = typer.Option(True, "--peers/--no-peers",
                                                    help="Run MiniRocket (aeon) and 1-NN DTW on the same clips (dev extras)."),
                         open_set: bool = typer.Option(True, "--open-set/--no-open-set",
                                                       help="Hold every class out in turn (about a minute per split)."),
                         association: bool = typer.Option(True, "--association/--no-association",
                                                          help="Estimate an arm robot's torques from each test clip's "
                                                               "motion (eq. 2.8; about 10 s per split).")):
    """Recognition report: leave-one-performer-out accuracy, per-class confusions, confidence
    calibration, unknown motions, association (motion -> torque) and time per clip, side by side
    with MiniRocket and DTW."""
    from shared.io import find_clips
    from shared.reports.evaluation import evaluate
    from shared.reports.evaluation_report import write_report

    folder = data / "amc" if (data / "amc").is_dir() else data
    if not folder.is_dir():
        fail(f"no clip folder at {folder} (give --data)")
    files = find_clips([folder])
    if not files:
        fail(f"no clips under {folder}")
    clips = [read_clip(f) for f in files]
    res = evaluate(clips, peers=peers, open_set_test=open_set, association=association,
                   progress=lambda m: typer.echo(m, err=True))
    path = write_report(res, out)
    typer.echo(f"wrote {path} and {out / 'results.json'}")
    for k, ok in res["verdicts"].items():
        typer.echo(f"  {k}: {'met' if ok else 'missed'}")


@offline_app.command("generate")
def space_generate(space_file: Path = typer.Argument(..., help="Space file."),
                   out: Path = typer.Option(..., "--out", help="Output clip (.bvh or .npz)."),
                   point: str | None = typer.Option(None, help="Point as comma-separated coordinates."),
                   mix: list[str] | None = typer.Option(None, help="NAME=W, repeatable; weights sum to 1 (may be negative)."),
                   method: str = typer.Option("expected", help="'expected' (deterministic) or 'monte_carlo'."),
                   seed: int = typer.Option(0, help="Seed of the Monte Carlo generation.")):
    """Generate a motion from a point or a weighted mix of proto-symbols (eq. 2.7, 4.2)."""
    from shared.io import save_clip
    from shared.pss.space import ProtoSymbolSpace

    if (point is None) == (not mix):
        fail("give exactly one of --point or --mix")
    space = ProtoSymbolSpace.load(space_file)
    if point is not None:
        clip = space.generate(parse_point(point), method=method, seed=seed, name=out.stem)
    else:
        clip = space.generate(weights=space.mix_weights(parse_mix(mix or [])), method=method, seed=seed, name=out.stem)
    save_clip(clip, out)
    typer.echo(f"wrote {out} ({clip.n_frames} frames at {clip.fps:g} fps)")


#: the command groups this module adds to ``app`` (the only ones registered so far)
OWN_GROUPS = tuple(g.name for g in app.registered_groups)
#: the modules that add the other command groups (and the root commands), with the groups each adds
COMMAND_MODULES = {"agents": ("sim", "other", "learner", "dialogue", "estimator"), "cluster": ("space",),
                   "coach": ("coach",), "study": ("study",), "deploy": ("deploy",), "capture": ("capture",)}


def register(group: str | None = None) -> None:
    """Import the modules that add commands to ``app``: the one that adds ``group`` (none for
    this module's own groups), or all of them (``None``, or a name no module adds: a root
    command). A program that uses ``app`` as a library calls ``register()`` first."""
    import importlib

    if group in OWN_GROUPS:
        return
    names = [m for m, groups in COMMAND_MODULES.items() if group in groups] or list(COMMAND_MODULES)
    for name in names:
        importlib.import_module(f"shared.cli.{name}")


def _group_of(argv: list[str]):
    """The command group ``argv`` starts with (``offline``, ``space``, ...), or None: a group's
    command is run by that group's click group alone, and only the module that adds it is
    imported (:func:`register`), so the command tree of every other group is not built (typer
    builds all 64 commands' click objects on every call: ~58 ms of `offline recognize`) nor
    imported (~5 ms)."""
    if not argv or argv[0].startswith("-"):
        register()
        return None  # root options (--units ...) or the root's help: the whole application
    register(argv[0])  # a root command (up, status, ...) or a misspelt one: every module, the whole application
    return next((g.typer_instance for g in app.registered_groups if g.name == argv[0]), None)


def main() -> None:
    try:
        group = _group_of(sys.argv[1:])
        if group is None:
            app()
        else:
            # as a group even with one command (typer runs a lone command's app as that command)
            typer.main.get_group(group).main(args=sys.argv[2:], prog_name=f"mirrorcoach {sys.argv[1]}")
    except MirrorcoachError as e:
        typer.echo(f"error: {e.message}", err=True)
        sys.exit(2)
    except ModuleNotFoundError as e:  # an optional part not installed: say which extra, not a traceback
        from shared.extras import hint_for

        hint = hint_for(e)
        if hint is None:
            raise
        typer.echo(f"error: {hint}", err=True)
        sys.exit(2)
    except KeyboardInterrupt:  # outside typer's own handling (choosing the group)
        typer.echo("interrupted", err=True)
        sys.exit(130)
    except SystemExit as e:
        # typer turns Ctrl-C in a command into a silent exit 130 (typer.core._main raises
        # Exit(130) from the KeyboardInterrupt); say so. A command that says more itself (reproduce)
        # raises its own Exit(130), not from the interrupt, and is left as it is.
        if e.code == 130 and isinstance(getattr(e.__context__, "__cause__", None), KeyboardInterrupt):
            typer.echo("interrupted", err=True)
        raise


if __name__ == "__main__":  # run the imported module, so the cluster commands are registered on its app
    from shared.cli.app import main as _main

    _main()
