"""Motion capture from other studios read with no options.

On every BVH of ``../shared/data/bandai1`` (a game studio: static floor root, 6 channels on
every joint, cm, bones along local X), both CMU conversions in ``../shared/data/cmu`` and the
HDM05 clips (AMC, and the BVH mirrorcoach writes from them):

* read with no options: upright (head above the feet along Y over the take), standing height,
  and the largest distance of any joint from an independent forward kinematics of the file
  (:mod:`bench.bvh_reference`, Blender's reading), in mm;
* the same motion in two formats: eq. 2.4 distance on the space's geometry (motion group)
  between an HDM05 AMC clip and the BVH written from it, against the distance to another take
  of the same motion by the same performer;
* a human body from each source's skeleton: mass, the largest segment share outside the
  trunk, peak joint torque of a walk (or the source's first clip);
* reading time per file.

Writes ``bench/results/mocap.json`` and ``mocap.md``. ``python -m bench.mocap --hdm05 DIR``.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

from bench.bvh_reference import read_positions
from bench.common import parse_args, write_results
from shared.errors import MirrorcoachError
from shared.io import find_clips, load_clip, save_clip
from shared.io.conventions import FOOT_RE, HEAD_RE
from shared.motion.skeleton import Joint, Skeleton


def _check_file(path: Path) -> dict:
    t0 = time.perf_counter()
    try:
        clip = load_clip(path)
    except MirrorcoachError as e:
        return {"file": path.name, "read": False, "error": str(e)}
    dt = time.perf_counter() - t0
    sk = clip.skeleton
    p = sk.forward_kinematics(clip.data, clip.channels, ends=False)
    heads = [i for i, j in enumerate(sk.joints) if HEAD_RE.search(j.name)]
    feet = [i for i, j in enumerate(sk.joints) if FOOT_RE.search(j.name)]
    up = p[:, heads, 1].mean(axis=1) - p[:, feet, 1].mean(axis=1)
    height = float(np.percentile(p[:, heads, 1].max(axis=1) - p[..., 1].min(axis=1), 90))
    out = {"file": path.name, "read": True, "read_s": dt, "upright": bool(np.median(up) > 0), "height_m": height,
           "read_as": clip.read_as}
    if path.suffix.lower() == ".bvh":
        names, ref = read_positions(path)
        ref = ref * sk.unit_m
        if clip.read_as.get("up", "").startswith("z"):
            ref = ref[..., [0, 2, 1]] * np.array([1.0, 1.0, -1.0])
        rows = [names.index(j.name) for j in sk.joints]
        out["fk_error_mm"] = float(1e3 * np.abs(ref[:, rows] - p).max())
    return out


def _space(hdm05: Path):
    """A space of HDM05 bd's and bk's clips (dg's kept out), and every clip."""
    from shared.pss.space import ProtoSymbolSpace

    clips = [load_clip(f) for f in find_clips([hdm05 / "amc"])]
    return ProtoSymbolSpace.build([c for c in clips if "_dg_" not in c.name]), clips


def _same_motion_in_two_formats(space, clips) -> list[dict]:
    from shared.pss.distance import hmm_distance

    geo = space.features.group_indices(("motion",))
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for label in sorted({c.label for c in clips}):
            takes = [c for c in clips if c.label == label and "_bd_" in c.name][:2]
            if len(takes) < 2:
                continue
            save_clip(takes[0], Path(tmp) / "a.bvh")
            bvh = load_clip(Path(tmp) / "a.bvh")
            h = [space.abstract(c).marginal(geo) for c in (takes[0], bvh, takes[1])]
            same, other = hmm_distance(h[0], h[1]), hmm_distance(h[0], h[2])
            rows.append({"motion": label, "amc_vs_bvh": same, "other_take": other, "ratio": same / other})
    return rows


def _across_performers(space, clips) -> list[dict]:
    """How far another performer's takes of a motion lie (dg, not in the space) against how far
    one performer's takes lie from each other (bd), on the joint rotations the coach's d_p
    reads (the motion group) and on joint positions: a representation that carries the Euler
    branch puts performers further apart on angles than on positions."""
    from itertools import combinations

    from shared.pss.distance import hmm_distance

    groups = {"rotations": space.features.group_indices(("motion",)),
              "positions": space.features.group_indices(("position",))}
    rows = []
    for label in sorted({c.label for c in clips}):
        bd = [space.abstract(c) for c in clips if c.label == label and "_bd_" in c.name][:3]
        dg = [space.abstract(c) for c in clips if c.label == label and "_dg_" in c.name][:3]
        if len(bd) < 2 or not dg:
            continue
        row = {"motion": label}
        for g, idx in groups.items():
            within = np.mean([hmm_distance(a.marginal(idx), b.marginal(idx)) for a, b in combinations(bd, 2)])
            across = np.mean([hmm_distance(a.marginal(idx), b.marginal(idx)) for a in bd for b in dg])
            row[g] = float(across / within)
        rows.append(row)
    return rows


def _body(source: str, clip) -> dict:
    from shared.bodies.body import perform
    from shared.bodies.human import human_body
    from shared.bodies.segments import map_segments

    body = human_body(clip.skeleton)
    seg, _ = map_segments(clip.skeleton)
    masses = {j.name: float(body.model.body(j.name).mass[0]) for j in clip.skeleton.joints}
    by_seg: dict = {}
    for bone, (s, side) in seg.items():
        by_seg[(s, side)] = by_seg.get((s, side), 0.0) + masses[bone]
    limb = max(v for (s, _), v in by_seg.items() if s not in ("pelvis", "spine"))
    sk = clip.skeleton  # the same skeleton with no bone names: segments from its tree and proportions alone
    anon = Skeleton(sk.name, [Joint(f"b{i:02d}", j.parent, j.offset, j.dofs, j.euler, j.pre, j.end, j.limits)
                              for i, j in enumerate(sk.joints)], sk.unit_m, sk.up_axis, sk.source_format)
    blind = human_body(anon)
    by_blind: dict = {}
    for i, j in enumerate(sk.joints):
        s, side = seg[j.name]
        key = ("forearm+hand" if s in ("forearm", "hand") else s, side)
        pair = by_blind.setdefault(key, [0.0, 0.0])
        pair[0] += masses[j.name]
        pair[1] += float(blind.model.body(f"b{i:02d}").mass[0])
    unnamed = max(abs(b - a) / a for a, b in by_blind.values() if a > 0)
    performed, report = perform(body, clip)
    tau = performed.select([c for c in performed.group("sensor") if c.startswith("tau.") and c.rsplit(".", 1)[1][0] == "r"])
    return {"source": source, "clip": clip.name, "mass_kg": float(body.mass), "largest_limb_share": limb / body.mass,
            "peak_torque_Nm": float(np.abs(tau).max()), "unmapped": body.unmapped,
            "unnamed_segment_mass_error": unnamed, "unnamed_unusual": blind.unmapped,
            "airborne_frames": report["support"].get("frames_airborne"), "frames": clip.n_frames}


def main(argv=None) -> None:
    args = parse_args(__doc__, argv)
    shared_data = args.hdm05.parent
    sources = {"bandai1": sorted((shared_data / "bandai1" / "bvh").glob("*.bvh")),
               "cmu": sorted((shared_data / "cmu").glob("*.bvh")),
               "hdm05-amc": find_clips([args.hdm05 / "amc"])}
    files = {k: [_check_file(f) for f in v] for k, v in sources.items()}
    with tempfile.TemporaryDirectory() as tmp:  # the BVH mirrorcoach writes from HDM05
        written = []
        for f in sources["hdm05-amc"][::8]:
            out = Path(tmp) / (f.stem + ".bvh")
            save_clip(load_clip(f), out)
            written.append(_check_file(out))
        files["hdm05-written-bvh"] = written
    summary = {}
    for k, rows in files.items():
        ok = [r for r in rows if r["read"]]
        good = [r for r in ok if r["upright"] and 1.0 <= r["height_m"] <= 2.2 and r.get("fk_error_mm", 0.0) <= 1.0]
        summary[k] = {"files": len(rows), "read": len(ok), "upright_person_within_1mm": len(good),
                      "height_m": [min(r["height_m"] for r in ok), max(r["height_m"] for r in ok)] if ok else None,
                      "worst_fk_error_mm": max((r.get("fk_error_mm", 0.0) for r in ok), default=None),
                      "median_read_ms": float(1e3 * np.median([r["read_s"] for r in ok])) if ok else None}
    space, hdm05_clips = _space(args.hdm05)
    formats = _same_motion_in_two_formats(space, hdm05_clips)
    performers = _across_performers(space, hdm05_clips)
    walk = next(f for f in sources["bandai1"] if "_walk_normal_" in f.name)
    bodies = [_body("bandai1", load_clip(walk)), _body("cmu", load_clip(sources["cmu"][1]).frames(0, 600)),
              _body("hdm05", load_clip(next(f for f in sources["hdm05-amc"] if "jogLeftCircle" in f.name)))]
    res = {"summary": summary, "files": files, "formats": formats, "performers": performers, "bodies": bodies}
    md = ["# Motion capture from other studios, no options", "",
          "The reading rules were written looking at these files (bandai1, CMU, HDM05): this is the population they "
          "were tuned on, not one held out.", "",
          "| source | files | read | upright, 1.0-2.2 m, within 1 mm of the reference FK | standing height (m) | "
          "worst FK error (mm) | median read (ms) |", "|---|---|---|---|---|---|---|"]
    for k, s in summary.items():
        h = "-" if s["height_m"] is None else f"{s['height_m'][0]:.2f}-{s['height_m'][1]:.2f}"
        md.append(f"| {k} | {s['files']} | {s['read']} | {s['upright_person_within_1mm']} | {h} | "
                  f"{s['worst_fk_error_mm'] if s['worst_fk_error_mm'] is None else round(s['worst_fk_error_mm'], 4)} | "
                  f"{s['median_read_ms']:.1f} |")
    md += ["", "Same motion in two formats (HDM05 bd, eq. 2.4 on the motion group):", "",
           "| motion | AMC vs its BVH | vs another take | ratio |", "|---|---|---|---|"]
    md += [f"| {r['motion']} | {r['amc_vs_bvh']:.4g} | {r['other_take']:.4g} | {100 * r['ratio']:.3f} % |" for r in formats]
    md += ["", "Another performer against one performer's own takes (HDM05 dg, not in the space, vs bd; eq. 2.4 "
           "distance across / within; the coach's d_p reads the rotations):", "",
           "| motion | rotations (6-D) | joint positions |", "|---|---|---|"]
    md += [f"| {r['motion']} | {r['rotations']:.2f} | {r['positions']:.2f} |" for r in performers]
    md.append(f"| median | {np.median([r['rotations'] for r in performers]):.2f} | "
              f"{np.median([r['positions'] for r in performers]):.2f} |")
    md += ["", "Human bodies (70 kg asked):", "", "| source | clip | mass (kg) | largest limb segment | peak torque (N m) | "
           "unusual bones | bones renamed b00, b01, ...: largest segment mass change (forearm and hand as one) |",
           "|---|---|---|---|---|---|---|"]
    md += [f"| {b['source']} | {b['clip']} | {b['mass_kg']:.1f} | {100 * b['largest_limb_share']:.1f} % | "
           f"{b['peak_torque_Nm']:.0f} | {', '.join(b['unmapped']) or '-'} | {100 * b['unnamed_segment_mass_error']:.2f} %"
           f"{' (unusual: ' + ', '.join(b['unnamed_unusual']) + ')' if b['unnamed_unusual'] else ''} |" for b in bodies]
    write_results(args.out, "mocap", res, md)
    print("\n".join(md))


if __name__ == "__main__":
    main()
