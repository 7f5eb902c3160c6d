"""CLI commands that talk to the running cluster: ``space ...``, ``status``, ``up``, ``down``,
``schemas``. Clips are read here and sent as messages; the work happens in the services."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import typer

from shared.bus.wirefiles import wire_file, wire_name
from shared.cli.common import (
    JSON_OPTION,
    POSE_FLOOR_HELP,
    READING,
    SKELETON_HELP,
    TIMEOUT_HELP,
    app,
    busy,
    client,
    echo_damaged,
    fail,
    jsonable,
    load_clips,
    parse_mix,
    parse_point,
    pose_floor_for,
    read_clip,
    recognition_text,
    say_if_never_rejects,
    wire,
)

space_app = typer.Typer(help="Proto-symbol spaces on the pss service (needs `make up`).", no_args_is_help=True)
app.add_typer(space_app, name="space")


def _print_info(info: dict) -> None:
    typer.echo(f"space {info['space']}: {info['n_proto_symbols']} proto-symbols, {len(info['labels'])} labels, "
               f"dim {info['params']['dim']}, {info['params']['n_states']} HMM states, "
               f"{info['n_features']} features, stress-1 {info['stress1']:.3f}")
    say_if_never_rejects(info)


# ---------------------------------------------------------------------------- space
@space_app.command("build")
def space_build(name: str = typer.Argument(..., help="Name of the space (letters, digits, _ . -)."),
                paths: list[Path] = typer.Argument(..., help="Clip files or folders of clips (.amc, .bvh, .npz)."),
                label: str | None = typer.Option(None, help="Label of every clip (default: the clip's parent folder)."),
                dim: int = typer.Option(3, help="Dimension of the space."),
                states: int | None = typer.Option(None, help="HMM states (default: from the shortest clip, at most 15)."),
                group_by: str = typer.Option("clip", help="'clip': a proto-symbol per clip; 'label': one per label."),
                pose_floor: float | None = typer.Option(None, "--pose-floor", min=0.0, help=POSE_FLOOR_HELP),
                replace: bool = typer.Option(False, "--replace", help="Replace an existing space of that name."),
                skeleton: Path | None = typer.Option(None, "--skeleton", help=SKELETON_HELP),
                timeout: float | None = typer.Option(None, help=TIMEOUT_HELP),
                as_json: bool = typer.Option(False, "--json", help="Print the space's info as JSON.")):
    """Build a named space on the pss service from clips (eq. 2.5)."""
    clips = load_clips(paths, skeleton, label)
    req = {"space": name, "clips": [wire(c) for c in clips], "dim": dim, "group_by": group_by, "replace": replace}
    if states is not None:
        req["n_states"] = states
    floor = pose_floor_for(pose_floor, [c.label or c.name for c in clips])
    if floor is not None:
        req["pose_floor"] = floor
    with client() as c, busy(f"building space {name} from {len(clips)} clips"):
        info = c.request("pss", "build", req, timeout=timeout)
    if as_json:
        typer.echo(json.dumps(jsonable(info)))
    else:
        _print_info(info)


@space_app.command("list")
def space_list(as_json: bool = JSON_OPTION):
    """Every space on the pss service (and any build that was interrupted)."""
    with client() as c:
        r = c.request("pss", "list", timeout=30)
    if as_json:
        typer.echo(json.dumps(jsonable(r)))
        return
    if not r["spaces"] and not r["damaged"]:
        typer.echo("no spaces (build one with `mirrorcoach space build NAME CLIPS...`)")
    for s in r["spaces"]:
        typer.echo(f"{s['space']:<24} {s['n_proto_symbols']:>4} proto-symbols  {len(s['labels']):>3} labels  "
                   f"dim {s['dim']}  stress-1 {s['stress1']:.3f}")
    for i in r["interrupted"]:
        typer.echo(f"{i['space']:<24} INTERRUPTED: its {i['operation']} never finished (the service stopped); "
                   "build it again or delete it")
    echo_damaged(r["damaged"])


@space_app.command("show")
def space_show(name: str = typer.Argument(..., help="Space name."), as_json: bool = JSON_OPTION):
    """A space's proto-symbols, points, parameters and stress."""
    with client() as c:
        info = c.request("pss", "info", {"space": name}, timeout=30)
    if as_json:
        typer.echo(json.dumps(jsonable(info)))
        return
    _print_info(info)
    for s, p in zip(info["proto_symbols"], info["points"]):
        typer.echo(f"  {s['label']:<30} {s['name']:<45} ({', '.join(f'{v:8.3f}' for v in p)})")


@space_app.command("recognize")
def space_recognize(name: str = typer.Argument(..., help="Space name."),
                    clips: list[Path] = typer.Argument(..., help="Clip(s): several are repetitions of one motion."),
                    top: int = typer.Option(5, help="How many nearest proto-symbols to list."),
                    skeleton: Path | None = typer.Option(None, "--skeleton", help=SKELETON_HELP),
                    timeout: float | None = typer.Option(None, help=TIMEOUT_HELP),
                    as_json: bool = typer.Option(False, "--json", help="label, point, nearest as JSON.")):
    """Recognise a motion as a point of the space (eq. 2.6) and list its nearest proto-symbols."""
    import os
    import time

    t_body = time.perf_counter()
    # the files go as they are (the performer's own body: positions are theirs); the service
    # reads them, so this command starts without numpy (docs/pss.md, "How a motion is recognised")
    files = [wire_file(p, skeleton=skeleton) for p in clips]
    with client(arrays="lists") as c:
        r = c.request("pss", "recognize", {"space": name, "files": files, "top": top,
                                           **{k: v for k, v in READING.items() if v is not None}}, timeout=timeout)
    if os.environ.get("MIRRORCOACH_TIMING"):  # for bench/bus.py: the command's own time, start-up excluded
        typer.echo(f"timing: command {1e3 * (time.perf_counter() - t_body):.2f} ms, library {1e3 * r['seconds']:.2f} ms",
                   err=True)
    if as_json:
        typer.echo(json.dumps(jsonable(r)))
        return
    typer.echo(recognition_text(r))


@space_app.command("generate")
def space_generate(name: str = typer.Argument(..., help="Space name."),
                   out: Path = typer.Option(..., "--out", help="Output clip (.bvh, .npz or .amc)."),
                   point: str | None = typer.Option(None, help="Point as comma-separated coordinates."),
                   mix: list[str] | None = typer.Option(None, help="LABEL=W or NAME=W, repeatable; weights sum to 1 (may be negative)."),
                   method: str = typer.Option("expected", help="'expected' (deterministic) or 'monte_carlo'."),
                   seed: int = typer.Option(0, help="Seed of the Monte Carlo generation."),
                   timeout: float | None = typer.Option(None, help=TIMEOUT_HELP),
                   as_json: bool = JSON_OPTION):
    """Generate a motion from a point or a mix of proto-symbols (eq. 2.7, 4.2) and write it."""
    from schemas.common import clip_from_wire
    from shared.io import save_clip

    if (point is None) == (not mix):
        fail("give exactly one of --point or --mix")
    req = {"space": name, "method": method, "seed": seed, "name": wire_name(out.stem)}
    if point is not None:
        req["point"] = parse_point(point)
    else:
        req["mix"] = parse_mix(mix or [])
    with client() as c:
        r = c.request("pss", "generate", req, timeout=timeout)
    clip = clip_from_wire(r["clip"])
    save_clip(clip, out)
    if as_json:
        typer.echo(json.dumps({"file": str(out), "frames": clip.n_frames, "fps": clip.fps,
                               "point": r["point"].tolist(), "weights": r["weights"].tolist()}))
    else:
        typer.echo(f"wrote {out} ({clip.n_frames} frames at {clip.fps:g} fps) from point "
                   f"({', '.join(f'{v:.3f}' for v in r['point'])})")


@space_app.command("add")
def space_add(name: str = typer.Argument(..., help="Space name."),
              paths: list[Path] = typer.Argument(..., help="Clip files or folders to add, one proto-symbol each."),
              label: str | None = typer.Option(None, help="Label for every clip (default: parent folder name)."),
              rebuild: bool = typer.Option(False, "--rebuild/--place",
                                           help="--place (default): the new proto-symbols' points are placed among "
                                                "the fixed ones, N distances per clip; --rebuild: every point embedded "
                                                "again (eq. 2.5), N^2 distances."),
              skeleton: Path | None = typer.Option(None, "--skeleton", help=SKELETON_HELP),
              timeout: float | None = typer.Option(None, help=TIMEOUT_HELP),
              as_json: bool = JSON_OPTION):
    """Add clips to a space as new proto-symbols, without rebuilding the rest by default."""
    clips = load_clips(paths, skeleton, label)
    with client() as c, busy(f"adding {len(clips)} clips to {name}"):
        info = c.request("pss", "add", {"space": name, "clips": [wire(x) for x in clips], "rebuild": rebuild},
                         timeout=timeout)
    if as_json:
        typer.echo(json.dumps(jsonable(info)))
    else:
        _print_info(info)


@space_app.command("associate")
def space_associate(name: str = typer.Argument(..., help="Space name."),
                    clip: Path = typer.Argument(..., help="The partial clip (.amc, .bvh or .npz)."),
                    missing: str = typer.Option("sensor", help="What the clip lacks: 'sensor' (its torques and centre "
                                                                "of gravity, from its motion) or 'frames' (the rest of "
                                                                "a motion, from its start)."),
                    out: Path | None = typer.Option(None, "--out", help="Write the estimate: the clip with its "
                                                                           "sensor channels (.npz), or the whole motion "
                                                                           "(.bvh, .npz or .amc)."),
                    skeleton: Path | None = typer.Option(None, "--skeleton", help=SKELETON_HELP),
                    timeout: float | None = typer.Option(None, help=TIMEOUT_HELP),
                    as_json: bool = JSON_OPTION):
    """Associate (eq. 2.8): what the space's proto-symbols say of the part a clip lacks, and
    whether the clip lies within what the space learnt or the estimate extrapolates."""
    from schemas.common import clip_from_wire
    from shared.io import save_clip

    if missing not in ("sensor", "frames"):
        fail(f"--missing must be 'sensor' or 'frames', got {missing!r}")
    partial = read_clip(clip, skeleton=skeleton)
    with client() as c:
        r = c.request("pss", "associate", {"space": name, "clip": wire(partial), "missing": missing}, timeout=timeout)
    est = clip_from_wire(r.get("aligned") or r["whole"])
    if out is not None:
        save_clip(est, out)
    sensors = est.group("sensor") if missing == "sensor" else []
    peaks = {ch: float(abs(est.column(ch)).max()) for ch in sensors}
    summary = {"space": name, "label": r["label"], "point": r["point"].tolist(), "reach": r.get("reach"),
               "extrapolating": r.get("extrapolating"), "progress": r.get("progress"), "frames": est.n_frames,
               "sensor_peaks": peaks, **({"file": str(out)} if out is not None else {})}
    if as_json:
        typer.echo(json.dumps(summary))
        return
    where = ("beyond what the space learnt: the estimate extrapolates" if r.get("extrapolating")
             else "within what the space learnt")
    typer.echo(f"{clip.name}: nearest {r['label'] or 'none of these'}; {where}"
               + (f" (reach {r['reach']:.2f}: its nearest proto-symbol over the space's own spacing)"
                  if r.get("reach") is not None else ""))
    if r.get("progress") is not None:
        typer.echo(f"the clip reaches {100 * r['progress']:.0f} % of the motion")
    for ch, v in peaks.items():
        typer.echo(f"  {ch}: peak {v:.3g}")
    if out is not None:
        typer.echo(f"wrote {out} ({est.n_frames} frames at {est.fps:g} fps)")


@space_app.command("delete")
def space_delete(name: str = typer.Argument(..., help="Space name.")):
    """Delete a space from the pss service (and its file)."""
    with client() as c:
        c.request("pss", "delete", {"space": name}, timeout=30)
    typer.echo(f"deleted space {name}")


# ---------------------------------------------------------------------------- cluster
@app.command("status")
def status(as_json: bool = JSON_OPTION):
    """Each process of the cluster: alive, FROZEN (stopped by SIGSTOP), RESTARTING or DOWN (exit 1
    if any is not alive)."""
    from shared.bus.cluster import status as cluster_status

    rows = cluster_status()
    if as_json:
        typer.echo(json.dumps(rows))
    else:
        for r in rows:
            state = r.get("state", "alive" if r["alive"] else "down")
            typer.echo(f"{r['name']:<12} {state if r['alive'] else state.upper():<10} pid {r['pid'] or '-'}")
    if not all(r["alive"] for r in rows):
        raise typer.Exit(1)


@app.command("up")
def up(wait: float = typer.Option(120.0, help="Seconds to wait for every service to be alive.")):
    """Start the local cluster (router + services of shared/bus/cluster.toml) in the background."""
    from shared.bus.cluster import up as cluster_up

    raise typer.Exit(cluster_up(wait_s=wait, echo=typer.echo))


@app.command("down")
def down():
    """Stop the local cluster."""
    from shared.bus.cluster import down as cluster_down

    raise typer.Exit(cluster_down(echo=typer.echo))


@app.command("schemas")
def schemas(service: str | None = typer.Argument(None, help="Only this service's contract.")):
    """Print every request and reply of every service (the contracts in schemas/)."""
    from schemas import CONTRACTS

    if service is not None and service not in CONTRACTS:
        fail(f"no service {service!r}; services: {', '.join(CONTRACTS)}")
    for name, mod in CONTRACTS.items():
        if service is not None and name != service:
            continue
        typer.echo(f"# {name}  (keys {'<prefix>'}/{name}/<verb>)\n")
        for ep in mod.ENDPOINTS.values():
            typer.echo(f"## {name}/{ep.verb}: {ep.doc}")
            typer.echo("limit    " + ("waits for a person: its request's timeout" if ep.waits
                                      else f"stops at a safe point after {ep.time_limit_s:g} s"))
            typer.echo("request  " + ep.request.describe())
            typer.echo("reply    " + ep.reply.describe())
            typer.echo("")
        for topic, msg in getattr(mod, "EVENTS", {}).items():
            typer.echo(f"## event <prefix>/events/{name}/{topic}")
            typer.echo(msg.describe())
            typer.echo("")
    if service is None:
        from schemas.common import ERROR

        typer.echo("# every error (reply_err)\n" + ERROR.describe())


@app.command("dashboard")
def dashboard(recording: Path | None = typer.Argument(None, help="A .rrd file (default: the latest recording)."),
              screenshot: Path | None = typer.Option(None, help="Instead of opening a window, open the recording "
                                                                     "in the real viewer without a screen and save a "
                                                                     "screenshot of every tab into this folder (needs "
                                                                     "Mesa's Vulkan driver: apt-get install "
                                                                     "mesa-vulkan-drivers libvulkan1).")):
    """Open the rerun viewer on the cluster's recording, or say where it is and how to open it."""
    import os
    import shutil
    import subprocess

    from shared.bus.config import Settings

    path = recording or (Settings().home / "recordings" / "latest.rrd")
    if not path.exists():
        fail(f"no recording at {path}: run `make demo` (or `make up` and use the cluster) first")
    path = path.resolve()
    if screenshot is not None:
        from shared.errors import MirrorcoachError
        from shared.observe.viewer import dashboard_screenshots

        try:
            for p in dashboard_screenshots(path, screenshot, log=Settings().log_dir / "viewer.log"):
                typer.echo(f"wrote {p}")
        except MirrorcoachError as e:
            fail(e.message)
        except ConnectionError as e:  # the viewer's own refusal (rerun.experimental.ViewerClient)
            fail(f"the rerun viewer refused: {str(e).splitlines()[0]}")
        except OSError as e:
            fail(f"could not write the screenshots to {screenshot}: {e.strerror or e}")
        return
    viewer = shutil.which("rerun") or str(Path(sys.executable).parent / "rerun")
    if (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")) and Path(viewer).exists():
        subprocess.run([viewer, "analytics", "disable"], capture_output=True, timeout=60)
        typer.echo(f"opening {path} in the rerun viewer (analytics disabled)")
        from shared.observe.viewer import viewer_command

        subprocess.Popen(viewer_command(viewer, path), start_new_session=True)
        return
    typer.echo(f"no display here. The recording is {path}\n"
               f"Open it where there is one: `pip install rerun-sdk==0.41.0 && rerun analytics disable && rerun {path.name}`\n"
               f"or take screenshots of it in the viewer here: `mirrorcoach dashboard --screenshot docs/dashboard`")
