"""``make bench`` (bus part): what the bus adds on top of the library (with their targets).

On a private cluster (free loopback port, temporary home) started with ``shared.bus.cluster.up``:

* request overhead for a 100 KB payload, (a) raw Zenoh get/reply through the router and
  (b) the full service stack (msgpack codec, contract validation, worker pool, reply
  validation) on the ``echo`` service of ``bench/echo.py`` (target <= 1 ms median);
* recognition through the CLI end to end (``mirrorcoach space recognize``, the installed
  command, a subprocess per call): the wall time of one call including start-up (target <= 150
  ms); the command's own time (``MIRRORCOACH_TIMING=1``: reading the file's bytes,
  opening the session, the request with the service's reading of the file, the reply) and the
  library's time reported by the service; the rest is start-up and exit (interpreter,
  imports, typer's argument parsing);
* the same recognition without a cluster (``mirrorcoach offline recognize`` on the space saved
  as a file, target <= 150 ms), beside an interpreter that only imports numpy and typer;
* 20 concurrent recognitions on one space: throughput and 95th-percentile latency.

Writes ``bench/results/bus.json`` and ``bench/results/bus.md``.
"""

from __future__ import annotations

import os
import re
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from bench.common import concurrent, parse_args, private_cluster, stats, write_results


def raw_zenoh_roundtrip(settings, n=300, size=100_000) -> dict:
    import zenoh

    from shared.bus.config import client_config

    payload = os.urandom(size)
    srv = zenoh.open(client_config(settings))
    q = srv.declare_queryable(settings.key("rawecho", "x"), lambda query: (query.reply(query.key_expr, query.payload), query.drop()))
    cli = zenoh.open(client_config(settings))
    time.sleep(0.5)
    ts = []
    for i in range(n + 20):
        t0 = time.perf_counter()
        got = [r.ok.payload.to_bytes() for r in cli.get(settings.key("rawecho", "x"), payload=payload, timeout=5)]
        if i >= 20:
            ts.append(time.perf_counter() - t0)
        assert got and len(got[0]) == size
    q.undeclare()
    cli.close()
    srv.close()
    return stats(ts)


def offline_recognize(cmd: list[str], train: list, probe_file: Path, n: int = 20) -> dict:
    """Wall time of ``mirrorcoach offline recognize`` (a subprocess per call, after two warm-ups)
    and of an interpreter that only imports numpy and typer, the floor under any command that
    computes with arrays."""
    import tempfile

    from shared.pss.space import ProtoSymbolSpace

    def walls(argv: list[str]) -> list[float]:
        ts = []
        for _ in range(n + 2):
            t0 = time.perf_counter()
            subprocess.run(argv, capture_output=True, check=True)
            ts.append(time.perf_counter() - t0)
        return ts[2:]

    with tempfile.TemporaryDirectory() as tmp:
        space_file = Path(tmp) / "bench.npz"
        ProtoSymbolSpace.build(train).save(space_file)
        rec = walls(cmd + ["offline", "recognize", str(space_file), str(probe_file)])
    floor = walls([sys.executable, "-c", "import numpy, typer"])
    return {"wall_ms": 1e3 * statistics.median(rec), "wall_p90_ms": 1e3 * float(np.percentile(rec, 90)),
            "floor_ms": 1e3 * statistics.median(floor), "space_clips": len(train)}


def build_200(c, clips) -> dict:
    """``pss/build`` of 200 HDM05 clips (the 188 of the dev data and 12 of them played 10 % slower)
    through the cluster, and the same build, calibration and save in this process."""
    import tempfile

    from schemas.common import clip_to_wire
    from shared.pss.space import ProtoSymbolSpace

    clips = [x.resample(30) for x in clips]
    slower = [x.with_data(x.data, name=f"{x.name}-slower", fps=27.0).resample(30) for x in clips[:200 - len(clips)]]
    clips = (clips + slower)[:200]
    wire = [clip_to_wire(x) for x in clips]
    cluster, library = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(3):
            t0 = time.perf_counter()
            c.request("pss", "build", {"space": f"b200-{i}", "clips": wire}, timeout=600)
            cluster.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            ProtoSymbolSpace.build(clips).save(Path(tmp) / f"{i}.npz")
            library.append(time.perf_counter() - t0)
    cl, lb = statistics.median(cluster), statistics.median(library)
    return {"clips": len(clips), "cluster_s": cl, "library_s": lb, "ratio": cl / lb, "runs": 3}


def main(argv=None) -> int:
    args = parse_args(__doc__, argv)
    from schemas.common import clip_to_wire
    from shared.bus.client import Client
    from shared.io import find_clips, load_clip

    res: dict = {}
    with private_cluster("bench") as s, Client(s) as c:
        echo = subprocess.Popen([sys.executable, "-m", "bench.echo"],
                                stderr=subprocess.DEVNULL)
        try:
            deadline = time.monotonic() + 60
            while "echo" not in c.alive() and time.monotonic() < deadline:
                time.sleep(0.1)
            # ---- 100 KB request overhead
            res["raw_zenoh_100KB"] = raw_zenoh_roundtrip(s)
            blob = np.random.default_rng(0).normal(size=12_500)  # 100,000 bytes
            ts = []
            for i in range(320):
                t0 = time.perf_counter()
                r = c.request("echo", "echo", {"blob": blob})
                if i >= 20:
                    ts.append(time.perf_counter() - t0)
            assert np.array_equal(r["blob"], blob)
            res["service_stack_100KB"] = stats(ts)
            print(f"100 KB request: raw zenoh {res['raw_zenoh_100KB']['median_ms']:.2f} ms, "
                  f"full service stack {res['service_stack_100KB']['median_ms']:.2f} ms (median)")

            # ---- a space of the dev clips, recognition through the CLI
            files = find_clips([args.hdm05 / "amc"])
            train = [load_clip(f) for f in files if "_dg_" not in f.name]
            probe_file = next(f for f in files if "_dg_" in f.name and "squat1Reps" in f.name)
            c.request("pss", "build", {"space": "bench", "clips": [clip_to_wire(x.resample(30)) for x in train]})
            env = dict(os.environ)
            script = Path(sys.executable).parent / "mirrorcoach"  # what a user runs (`make install` puts it there)
            cmd = [str(script)] if script.exists() else [sys.executable, "-m", "shared.cli"]
            env["MIRRORCOACH_TIMING"] = "1"
            walls, cmds, libs = [], [], []
            for _ in range(32):  # the first two are a warm-up
                t0 = time.perf_counter()
                out = subprocess.run(cmd + ["space", "recognize", "bench", str(probe_file), "--json"], env=env,
                                     capture_output=True, check=True, text=True)
                walls.append(time.perf_counter() - t0)
                m = re.search(r"timing: command ([0-9.]+) ms, library ([0-9.]+) ms", out.stderr)
                cmds.append(float(m.group(1)) / 1e3)
                libs.append(float(m.group(2)) / 1e3)
            ee, cm, lb = (statistics.median(v[2:]) for v in (walls, cmds, libs))
            p90 = float(np.percentile(walls[2:], 90))
            res["cli_recognize"] = {"startup_ms": 1e3 * (ee - cm), "wall_ms": 1e3 * ee, "wall_p90_ms": 1e3 * p90,
                                    "command_ms": 1e3 * cm, "library_ms": 1e3 * lb, "over_library_ms": 1e3 * (cm - lb),
                                    "space_clips": len(train), "command": Path(cmd[0]).name}
            print(f"CLI recognition: wall {1e3 * ee:.0f} ms (p90 {1e3 * p90:.0f}) = start-up and exit {1e3 * (ee - cm):.0f} "
                  f"+ command {1e3 * cm:.0f} (library {1e3 * lb:.0f} + {1e3 * (cm - lb):.0f} ms over the library)")

            # ---- the same recognition without a cluster: `offline recognize` on the space saved as a file
            res["offline_recognize"] = offline_recognize(cmd, train, probe_file)
            o = res["offline_recognize"]
            print(f"offline recognition: wall {o['wall_ms']:.0f} ms (p90 {o['wall_p90_ms']:.0f}); python + numpy + typer "
                  f"alone {o['floor_ms']:.0f} ms")

            # ---- a 200-clip space: built through the cluster against the library on the same clips
            res["build_200"] = build_200(c, [load_clip(f) for f in files])
            b = res["build_200"]
            print(f"200-clip space: cluster {b['cluster_s']:.2f} s, library (build and save) {b['library_s']:.2f} s, "
                  f"ratio {b['ratio']:.2f}")

            # ---- 20 concurrent recognitions on one space
            probe = clip_to_wire(load_clip(probe_file), with_skeleton=False)

            def recognize(_):
                c.request("pss", "recognize", {"space": "bench", "clips": [probe]})

            recognize(0)  # warm-up
            res["concurrent_20"] = concurrent(recognize, 20, 5)
            print(f"20 concurrent recognitions: {res['concurrent_20']['throughput_per_s']:.0f} /s, "
                  f"latency median {res['concurrent_20']['median_ms']:.0f} ms, p95 {res['concurrent_20']['p95_ms']:.0f} ms")
        finally:
            echo.terminate()
            echo.wait(timeout=30)

    cr, cc, b, o = res["cli_recognize"], res["concurrent_20"], res["build_200"], res["offline_recognize"]
    md = [
        "# Bus benchmark (`make bench`, bench/bus.py)", "",
        "Private cluster on a free loopback port; medians after a warm-up.", "",
        "| what | measured | target |", "|---|---|---|",
        f"| 100 KB get/reply, raw Zenoh through the router | {res['raw_zenoh_100KB']['median_ms']:.2f} ms (p95 {res['raw_zenoh_100KB']['p95_ms']:.2f}) | - |",
        f"| 100 KB request, full service stack (codec, contract, pool) | {res['service_stack_100KB']['median_ms']:.2f} ms (p95 {res['service_stack_100KB']['p95_ms']:.2f}) | <= 1 ms |",
        f"| `mirrorcoach space recognize` of one AMC clip, wall including start-up (median of 30) | {cr['wall_ms']:.0f} ms (p90 {cr['wall_p90_ms']:.0f}) | <= 150 ms |",
        f"| of which start-up and exit (interpreter, imports, typer parsing) | {cr['startup_ms']:.0f} ms | reported |",
        f"| of which the command (file bytes, session, request incl. the service reading the file, reply) / library | {cr['command_ms']:.0f} / {cr['library_ms']:.0f} ms | - |",
        f"| `mirrorcoach offline recognize` of the same clip on the same space saved as a file, wall including start-up (median of 20) | {o['wall_ms']:.0f} ms (p90 {o['wall_p90_ms']:.0f}) | <= 150 ms |",
        f"| of which the interpreter importing numpy and typer, nothing else (the floor of a command that computes; median of 20) | {o['floor_ms']:.0f} ms | reported |",
        f"| 20 concurrent recognitions ({cr['space_clips']}-clip space) | {cc['throughput_per_s']:.0f} /s, p95 {cc['p95_ms']:.0f} ms, median {cc['median_ms']:.0f} ms | reported |",
        f"| `pss/build` of 200 clips through the cluster (request to reply, median of 3) | {b['cluster_s']:.2f} s | <= 15 s |",
        f"| the same in the library (build, calibration, save; same process, median of 3) / ratio | {b['library_s']:.2f} s / {b['ratio']:.2f}x | <= 1.5x |",
    ]
    write_results(args.out, "bus", res, md)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
