"""``make demo``: the Proto-symbol Space on real motion capture, on the running cluster.

Starts the local cluster if it is not running (``mirrorcoach up``: router + services on
127.0.0.1), then, through the bus only:

1. builds the space ``demo`` on the pss service from the bundled HDM05 clips of actors bd and
   bk (``data/hdm05``, so it works on a fresh clone), with arm torques from the MuJoCo arm as
   sensor channels;
2. recognises the held-out clips of actor dg (motion only) and associates their torques
   (eq. 2.6, 2.8);
3. generates an interpolated motion (half squat, half kick) and an extrapolated, emphatic one
   (eq. 4.3 with alpha = 2: a squat pushed away from another actor's squat) to BVH;
4. coaches a simulated learner on a real squat for 4 trials (coach service), printing each
   trial's alpha, adverb and d_p;
5. runs a short estimator conversation with a simulated other (chapter 3);
6. coaches a person's take live: four squats of actor bd joined with rests, replayed through
   the capture service like a capture suit's stream, cut into repetitions automatically (and
   again with each repetition named by a space of the motions alone, ``demo-moves``), one trial
   on the coach, the next demonstration written and its adverb said into a .wav;

says what it did, and stops the cluster again if it started it (``--keep-running`` leaves it up).
With ``MIRRORCOACH_DEPLOY`` set (a cluster across hosts) it runs the same steps on that
cluster as that identity and starts or stops nothing.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from schemas.common import clip_from_wire, clip_to_wire
from shared.bodies.arm import arm_model, with_arm_torques
from shared.bus.client import Client, Unavailable
from shared.bus.cluster import down, running, up
from shared.bus.config import Settings
from shared.io import find_clips, load_clip, save_clip

BUNDLED = Path(__file__).resolve().parent.parent / "data" / "hdm05" / "amc"


def run(client: Client, data: Path, out: Path) -> None:
    t0 = time.perf_counter()
    clips = [load_clip(f) for f in find_clips([data])]
    train = [c for c in clips if "_dg_" not in c.name]
    held_out = [c for c in clips if "_dg_" in c.name]
    print(f"read {len(clips)} HDM05 clips from {data} ({len(train)} of actors bd/bk to learn, {len(held_out)} of dg held out)")

    model = arm_model(body_mass=2.4)
    info = client.request("pss", "build", {"space": "demo", "replace": True,
                                           "clips": [clip_to_wire(with_arm_torques(c, model)) for c in train]})
    print(f"pss built space 'demo': {info['n_proto_symbols']} proto-symbols, {info['params']['n_states']}-state HMMs, "
          f"{info['n_features']} features (motion + 3 arm torques), stress-1 {info['stress1']:.3f}")

    print("recognised the held-out clips (actor dg, motion only) and associated their arm torques (eq. 2.6, 2.8):")
    correct = 0
    for c in held_out:
        a = client.request("pss", "associate", {"space": "demo", "clip": clip_to_wire(c), "missing": "sensor"})
        correct += a["label"] == c.label
        tau = clip_from_wire(a["aligned"])
        tau = tau.select(tau.group("sensor"))
        print(f"  {c.name:<45} -> {a['label']:<30} {'ok' if a['label'] == c.label else 'WRONG'}   "
              f"estimated mean |torque| {np.abs(tau).mean():.3f} N m")
    print(f"  {correct}/{len(held_out)} correct")

    rows = info["proto_symbols"]
    squat = next(r["name"] for r in rows if r["label"] == "squat1Reps" and "_bd_" in r["name"])
    kick = next(r["name"] for r in rows if r["label"] == "kickLFront1Reps")
    learner = next(r["name"] for r in rows if r["label"] == "squat1Reps" and "_bk_" in r["name"])

    g = client.request("pss", "generate", {"space": "demo", "mix": {squat: 0.5, kick: 0.5}, "name": "interpolated_squat_kick"})
    mid = clip_from_wire(g["clip"])
    save_clip(mid, out / "interpolated_squat_kick.bvh")
    r = client.request("pss", "recognize", {"space": "demo", "clips": [clip_to_wire(mid)], "top": len(rows)})
    d = {n["name"]: n["distance"] for n in r["nearest"]}
    pair = client.request("pss", "distance", {"space": "demo", "a": squat, "b": kick})["distance"]
    print(f"generated the midpoint of {squat} and {kick} -> {out / 'interpolated_squat_kick.bvh'} "
          f"(recognised between them: distances {d[squat]:.1f} / {d[kick]:.1f}; squat to kick {pair:.1f})")

    alpha = 2.0
    g = client.request("pss", "generate", {"space": "demo", "mix": {squat: 1 + alpha, learner: -alpha}, "name": "emphatic_squat"})
    emph = clip_from_wire(g["clip"])
    save_clip(emph, out / "emphatic_squat.bvh")
    r = client.request("pss", "recognize", {"space": "demo", "clips": [clip_to_wire(emph)], "top": len(rows)})
    d = {n["name"]: n["distance"] for n in r["nearest"]}
    print(f"generated the emphatic motion x_t + {alpha:g} (x_t - x_p) (eq. 4.3), target {squat}, learner {learner} -> "
          f"{out / 'emphatic_squat.bvh'} (recognised as {r.get('label') or 'none of these'}; distance to the target "
          f"{d[squat]:.1f}, to the learner {d[learner]:.1f})")
    coach_learner(client, next(c for c in train if c.label == "squat1Reps"), out)
    estimate_other(client)
    coach_live_take(client, next(c for c in train if c.label == "squat1Reps"),
                    [c for c in train if c.label == "squat1Reps" and "_bd_" in c.name], train, out)
    home = Settings().home
    print(f"done in {time.perf_counter() - t0:.1f} s. Outputs: BVH files in {out} (open in Blender or any BVH viewer); "
          f"the services' state (spaces, sessions, transcripts) in {home / 'data'}; the dashboard recording "
          f"{home / 'recordings' / 'latest.rrd'} (complete once the cluster stops; `make dashboard` opens it). "
          "Data: HDM05 (CC BY-SA 3.0), see data/hdm05/SOURCE.md.")


def coach_learner(client: Client, target, out: Path, trials: int = 4) -> None:
    """Coach a simulated learner (a simulation, not a person) on a real squat for 4 trials."""
    print(f"coaching simulated learner 'demo-learner' on {target.name} for {trials} trials "
          "(alpha 2 with Table 4.1's adverbs; the simulator checks every emphatic motion):")
    client.request("coach", "start", {"session": "demo", "target": clip_to_wire(target), "learner": "demo-learner",
                                      "index": 3, "policy": {"kind": "fixed", "alpha": 2.0, "adverb": "table"},
                                      "replace": True})
    info = client.request("coach", "run", {"session": "demo", "trials": trials})
    for t, r in zip(info["trials"], info["R"]):
        note = f" (lowered from {t['alpha']:g}: {t['feasibility']})" if t["alpha_reduced"] else ""
        print(f"  trial {t['number']}: d_p {t['d_p']:6.1f}  R {r:.2f}  alpha {t['alpha_shown']:g}  "
              f"\"{t['adverb'] or 'no adverb'}\"{note}")


def coach_live_take(client: Client, target, reps: list, train: list, out: Path) -> None:
    """A person's repetitions as one take through the capture service (a replay: the stand-in for
    a capture suit), cut automatically and coached for one trial; the adverb said into a .wav."""
    from shared.capture.speech import NoSpeech, speak
    from shared.capture.takes import join

    if "capture" not in client.alive():  # a deployed cluster that runs no capture service
        print("live take: skipped (this cluster runs no capture service)")
        return
    take, _ = join(reps * 2, seed=1)
    client.request("capture", "record", {"take": "demo-live", "replay": [clip_to_wire(take)], "speed": 4.0,
                                         "idle": 0.5, "replace": True})
    deadline = time.monotonic() + 120
    info = client.request("capture", "status", {"take": "demo-live"})
    while info["state"] == "recording" and time.monotonic() < deadline:
        time.sleep(0.2)
        info = client.request("capture", "status", {"take": "demo-live"})
    if info["state"] != "done":
        print(f"live take: {info['state']} ({info.get('error', info['ended'])})")
        return
    cut = client.request("capture", "segment", {"take": "demo-live", "target": clip_to_wire(target), "expected": 4})
    print(f"live take 'demo-live' ({info['frames']} frames from {info['source']}, played 4x): {cut['verdict']}, "
          + ", ".join(f"{r['start']:.1f}-{r['end']:.1f} s" for r in cut["repetitions"]))
    # a space of the motions alone (the space 'demo' models the arm's torques, which a take does not have)
    client.request("pss", "build", {"space": "demo-moves", "replace": True, "clips": [clip_to_wire(c) for c in train]})
    named = client.request("capture", "segment", {"take": "demo-live", "target": clip_to_wire(target), "expected": 4,
                                                  "space": "demo-moves"})
    print(f"  the same take, each repetition named by the space 'demo-moves' (eq. 2.6): {named['verdict']}, "
          + ", ".join(f"{r['start']:.1f}-{r['end']:.1f} s (ratio {r['cohort']:.2f})" for r in named["repetitions"]))
    if not cut["repetitions"]:
        return
    client.request("coach", "start", {"session": "demo-person", "target": clip_to_wire(target), "replace": True,
                                      "policy": {"kind": "fixed", "alpha": 2.0, "adverb": "table"}})
    r = client.request("coach", "attempt", {"session": "demo-person", "clips": cut["clips"]})
    demo = clip_from_wire(r["emphatic"]).resample(target.fps)
    save_clip(demo, out / "demo-person_trial2.bvh")
    said = ""
    if r.get("adverb"):
        try:
            speech = speak(r["adverb"], out / "demo-person_trial2.wav")
            said = f"; said into {out / 'demo-person_trial2.wav'} ({speech.seconds:.1f} s)"
        except NoSpeech as e:
            said = f"; not said aloud ({e.message})"
    print(f"  coached: d_p {r['d_p']:.1f}, next demonstration {out / 'demo-person_trial2.bvh'} "
          f"(alpha {r['alpha_shown']:g}), \"{r.get('adverb') or 'no adverb'}\"{said}")


def estimate_other(client: Client) -> None:
    """A short chapter-3 conversation: the self (2.4 kg) learns what a 4.8 kg other feels."""
    from shared.estimation.motions import unknown_motions

    client.request("simulator", "other_create", {"other": "demo-other", "params": {"mass": 4.8, "d": 6, "g_max": 0.6},
                                                 "replace": True})
    client.request("estimator", "start", {"estimate": "demo", "other": "demo-other", "d": 6, "replace": True})
    r = client.request("estimator", "converse", {"estimate": "demo", "sets": 2})
    m = unknown_motions(1)[0]
    e = client.request("estimator", "estimate", {"estimate": "demo", "clip": clip_to_wire(m), "method": "interval"})
    print(f"estimator: 2 conversation sets with a simulated other; its torques are {r['info']['scale']:.2f} x the "
          f"self's; an unknown motion would feel '{e['word']}' to it. Transcript: `mirrorcoach dialogue transcript demo`.")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", type=Path, default=BUNDLED, help="folder of AMC clips, one sub-folder per class")
    ap.add_argument("--out", type=Path, default=Path("out/demo"))
    ap.add_argument("--keep-running", action="store_true", help="leave the cluster up afterwards")
    args = ap.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    settings = Settings()
    started = False
    if settings.identity is not None:  # a deployed cluster (MIRRORCOACH_DEPLOY): its hosts run it; use it as it is
        print(f"on the deployed cluster at {settings.router} as {settings.identity.name!r} (TLS)")
    elif not running(settings):
        if up(settings) != 0:
            return 1
        started = True
    try:
        with Client(settings) as client:
            run(client, args.data, args.out)
    except Unavailable as e:
        print(f"error: {e.message}")
        return 1
    finally:
        if started and not args.keep_running:
            down(settings)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
