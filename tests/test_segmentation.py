"""Repetitions found in one continuous take (shared/capture/segment.py, shared/capture/takes.py)."""

import numpy as np
import pytest

from shared.capture import naming
from shared.capture import segment as seg
from shared.capture.takes import join, score
from shared.errors import BadInput
from shared.io import load_clip
from shared.motion.clip import time_normalised


def _clips(hdm05, performer, cls):
    return [load_clip(f) for f in sorted((hdm05 / "amc" / cls).glob(f"HDM_{performer}_*.amc"))]


def test_the_dtw_kernels_match_their_python_source():
    """The compiled kernels give what their plain-python source gives; a stretch equal to the
    target costs nothing, and the best stretch ending at a column starts where it really does."""
    r = np.random.default_rng(0)
    cost = np.ascontiguousarray(r.random((12, 40)))
    acc, start = seg.subsequence_dtw(cost)
    acc_py, start_py = seg.subsequence_dtw.py(cost)
    assert np.allclose(acc, acc_py) and np.array_equal(start, start_py)
    assert seg.global_dtw(cost[:, :15]) == pytest.approx(seg.global_dtw.py(cost[:, :15]))
    a = np.sin(np.linspace(0, 3, 20))[:, None]
    b = np.vstack([np.zeros((7, 1)), a, np.zeros((9, 1))])
    acc, start = seg.subsequence_dtw(seg.distances(a, b))
    assert acc[7 + 19] == pytest.approx(0.0) and start[7 + 19] == 7
    assert seg.global_dtw(seg.distances(a, a)) == pytest.approx(0.0)
    assert seg.global_dtw(seg.distances(a, a[:5])) == np.inf  # a slope steeper than 2 cannot join the ends


def _subsequence_dtw_whole(cost):
    """The reference: the accumulated cost and start of every cell kept (the form before the
    kernel kept three rows)."""
    n, m = cost.shape
    acc, start = np.full((n, m), np.inf), np.zeros((n, m), np.int64)
    acc[0], start[0] = 2.0 * cost[0], np.arange(m)
    for i in range(1, n):
        for j in range(1, m):
            c = cost[i, j]
            steps = [(acc[i - 1, j - 1] + 2.0 * c, start[i - 1, j - 1])]
            if j >= 2:
                steps.append((acc[i - 1, j - 2] + 2.0 * cost[i, j - 1] + c, start[i - 1, j - 2]))
            if i >= 2:
                steps.append((acc[i - 2, j - 1] + 2.0 * cost[i - 1, j] + c, start[i - 2, j - 1]))
            acc[i, j], start[i, j] = min(steps, key=lambda x: x[0])
    return acc[-1], start[-1]


def test_a_long_take_is_read_in_bounded_pieces_with_the_same_numbers(bundled, monkeypatch):
    """The kernel keeps three rows, distances come from scipy's cdist, a take's features and speed
    are read in blocks: each gives what the whole form gives (memory of a long take: bench.budget)."""
    r = np.random.default_rng(1)
    for n, m in ((1, 9), (2, 30), (12, 40), (30, 31)):
        cost = np.ascontiguousarray(r.random((n, m)))
        acc, start = seg.subsequence_dtw(cost)
        ref_acc, ref_start = _subsequence_dtw_whole(cost)
        finite = np.isfinite(ref_acc)
        assert np.array_equal(np.isfinite(acc), finite)
        assert np.allclose(acc[finite], ref_acc[finite]) and np.array_equal(start[finite], ref_start[finite])
    a, b = r.normal(size=(7, 5)), r.normal(size=(50, 5))
    assert np.allclose(seg.distances(a, b), np.sqrt(((a[:, None] - b[None]) ** 2).sum(-1)), atol=1e-12)
    clips = _clips(bundled, "bd", "squat1Reps")
    take, _ = join(clips * 3, seed=2)
    reader = seg.Reader(clips[0])
    whole, whole_speed = reader.read(take), seg.speed(reader.read(take), seg.FPS)
    monkeypatch.setattr(seg, "READ_BLOCK", 37)  # many blocks, a short last one merged into the one before
    assert len(whole) > 10 * 37
    assert np.allclose(reader.read(take), whole, atol=1e-12)
    assert np.array_equal(seg.speed(whole, seg.FPS), whole_speed)


def test_a_segmentation_past_its_time_limit_stops_with_the_limit_named(bundled):
    from shared.deadline import TimeLimit, time_limit

    clips = _clips(bundled, "bd", "squat1Reps")
    take, _ = join(clips * 2, seed=3)
    with time_limit(0.0, "capture/segment"), pytest.raises(TimeLimit, match="capture/segment passed its time limit"):
        seg.segment(take, clips[0])
    assert seg.segment(take, clips[0], expected=None).repetitions  # the same take without a limit is cut


def test_a_joined_take_holds_its_clips_where_it_says(bundled):
    two = _clips(bundled, "bk", "squat1Reps")[:2]
    clips = [two[0], two[1], two[0]]
    take, bounds = join(clips, seed=3)
    assert len(bounds) == 3 and take.channels == clips[0].channels and take.fps == clips[0].fps
    for clip, (s, e) in zip(clips, bounds):
        i = int(round(s * take.fps))
        assert e - s == pytest.approx(clip.duration + 1 / clip.fps, abs=1e-9)
        part = take.data[i:i + clip.n_frames]
        assert np.allclose(np.mod(part - clip.data + 180, 360) - 180, 0.0, atol=1e-6)  # whole turns aside
    assert bounds[1][0] - bounds[0][1] >= 1.0  # a rest between repetitions
    with pytest.raises(BadInput):
        join([])


def test_repetitions_of_the_same_performer_are_found_and_another_motion_is_not_cut(bundled):
    """Five squats of one performer (the bundled sample's, joined with rests of their own), the
    target another of that performer's squats: all five found, boundaries within 150 ms
    (median); a take of that performer's kicks holds no squat; three squats are "fewer"."""
    target, squat = _clips(bundled, "bk", "squat1Reps")[:2]
    take, truth = join([squat] * 5, seed=1)
    others = [_clips(bundled, "bd", c)[0] for c in ("kickLFront1Reps", "elbowToKnee1RepsLelbowStart",
                                                    "rotateArmsBothBackward1Reps")]
    found = seg.segment(take, target, expected=5, background=others)
    s = score([(r.start, r.end) for r in found.repetitions], truth)
    assert s["f1"] == 1.0 and np.median(s["boundary_errors"]) <= 0.15, (s, found.verdict)
    assert found.verdict == "5 repetition(s) found" and all(0 < r.confidence <= 1 for r in found.repetitions)
    assert all(r.cohort is not None and r.cohort <= seg.COHORT for r in found.repetitions)
    assert [c.n_frames for c in found.cut(take)] == [round((r.end - r.start) * take.fps) for r in found.repetitions]
    kicks, _ = join(_clips(bundled, "bk", "kickLFront1Reps") * 2, seed=2)
    none = seg.segment(kicks, target, expected=5, background=others)
    assert none.repetitions == [] and none.verdict.startswith("not the target")
    assert none.closest is not None and none.to_dict()["closest"] == pytest.approx(none.closest, abs=1e-4)
    fewer = seg.segment(join([squat] * 3, seed=1)[0], target, expected=5, background=others)
    assert fewer.verdict == "fewer repetitions than expected: 3 found, 5 expected"


def test_movements_lie_between_the_rests_and_shapes_forget_posture_and_size(bundled):
    """The rests of a joined take separate its movements: each true repetition lies inside one
    (give or take the way into its first pose); a stretch moved and scaled is the same shape."""
    squat = _clips(bundled, "bd", "squat1Reps")[0]
    take, truth = join([squat] * 3, seed=2)
    a, b = seg.features_of(squat, [take])
    moves = seg.movements(b, seg.REST_SHARE * float(np.mean(seg.speed(a, seg.FPS))), seg.FPS)
    assert len(moves) == 3, moves
    for (s, e), (ts, te) in zip(moves, truth):
        assert s / seg.FPS <= ts + 0.4 and e / seg.FPS >= te - 0.4 and (e - s) / seg.FPS <= (te - ts) + 1.0
    moved = 2.5 * a + 0.3
    assert seg.global_dtw(seg.distances(seg.shape(a), seg.shape(moved))) == pytest.approx(0.0, abs=1e-9)


@pytest.mark.parametrize("cls", ["elbowToKnee1RepsLelbowStart", "rotateArmsBothBackward1Reps", "squat1Reps"])
def test_another_performers_repetitions_are_found_and_other_motions_never_cut(bundled, cls):
    """The bundled sample's three performers: a take of bd's repetitions, the target bk's, the
    cohort dg's other motions: every repetition found; bd's takes of the other motions (kicks
    too) hold none. (bd's kicks against bk's are not found: their postures differ by more than
    the largest first cost allows; bench.segmentation measures such misses.)"""
    classes = ["elbowToKnee1RepsLelbowStart", "kickLFront1Reps", "rotateArmsBothBackward1Reps", "squat1Reps"]
    target = _clips(bundled, "bk", cls)[0]
    others = [_clips(bundled, "dg", o)[0] for o in classes if o != cls]
    take, truth = join(_clips(bundled, "bd", cls) * 2, seed=7)
    found = seg.segment(take, target, expected=4, background=others)
    assert score([(r.start, r.end) for r in found.repetitions], truth)["f1"] == 1.0, found.to_dict()
    for o in classes:
        if o != cls:
            assert seg.segment(join(_clips(bundled, "bd", o) * 2, seed=8)[0], target, background=others).repetitions == []


def test_bad_takes_are_refused_clearly(bundled):
    squat = _clips(bundled, "bk", "squat1Reps")[0]
    with pytest.raises(BadInput, match="skeleton"):
        seg.segment(squat.with_data(squat.data, skeleton=None), squat)
    with pytest.raises(BadInput, match="at least 1"):
        seg.segment(squat, squat, expected=0)
    with pytest.raises(BadInput, match="does not move"):
        still = squat.with_data(np.repeat(squat.data[:1], squat.n_frames, axis=0))
        seg.segment(squat, still)


def _swaying_take(bundled, cls: str, sway: float, monkeypatch):
    """Five repetitions of one clip, each 0.8-1.25x as fast, joined with rests that sway ``sway``
    degrees (the joined takes' sway is 0.3): rests that move faster than the rest level."""
    from dataclasses import replace

    from shared.capture import takes

    clip = _clips(bundled, "bk", cls)[0]
    r = np.random.default_rng(0)
    reps = [replace(clip.resample(clip.fps / float(r.uniform(0.8, 1.25))), fps=clip.fps) for _ in range(5)]
    monkeypatch.setattr(takes, "SWAY", sway)
    take, truth = join(reps, seed=2)
    return clip, take, truth


@pytest.mark.parametrize("cls, sway, without", [("kickLFront1Reps", 2.0, "ends"), ("elbowToKnee1RepsLelbowStart", 1.0, "fill")])
def test_repetitions_are_found_where_the_rests_move(bundled, monkeypatch, cls, sway, without):
    """Where a person's rests move faster than the rest level, the ends a rest gives are moved to
    where the target aligns best around them (``refine``) and the take between the repetitions is
    searched without its rests when fewer than expected were found (``fill``): every repetition
    found, its ends within 50 ms (median). Without them (``refine`` 0, ``fill`` off), these takes
    lose a repetition or put its ends 100 ms and more off."""
    from dataclasses import replace

    target, take, truth = _swaying_take(bundled, cls, sway, monkeypatch)

    def scored(how):
        found = seg.segment(take, target, expected=5, settings=how)
        return score([(r.start, r.end) for r in found.repetitions], truth), found

    s, found = scored(seg.Settings())
    assert s["f1"] == 1.0 and np.median(s["boundary_errors"]) <= 0.05, (s, found.verdict)
    assert found.verdict == "5 repetition(s) found"
    off, _ = scored(replace(seg.Settings(), refine=0.0, fill=False))
    if without == "ends":
        assert off["f1"] == 1.0 and np.median(off["boundary_errors"]) >= 0.1, off
    else:
        assert off["f1"] < 1.0, off
    kicks, _ = join(_clips(bundled, "bd", "kickLFront1Reps") * 2, seed=6)
    squat = _clips(bundled, "bk", "squat1Reps")[0]
    assert seg.segment(kicks, squat, expected=5).repetitions == []  # the searches start from a repetition taken


def test_tempos_the_slopes_cannot_join_are_compared_not_waved_through(bundled):
    """A stretch three times as long as another motion of the cohort was infinitely far from it
    (the DTW's slopes cannot join their ends), so its cohort ratio was 0 and any stretch passed
    the check: now it is compared at the nearest tempo the slopes can join."""
    squat = _clips(bundled, "bd", "squat1Reps")[0]
    a = seg.Reader(squat).target
    slow = time_normalised(a, 3 * len(a))
    assert seg.global_dtw(seg.distances(seg.shape(a), seg.shape(slow))) == np.inf
    near = seg._Template(a).cost(seg._Template(slow))
    assert np.isfinite(near) and near < 0.1
    kick = seg.Reader(squat).read(_clips(bundled, "bd", "kickLFront1Reps")[0])
    assert seg._Template(a).cost(seg._Template(time_normalised(kick, 3 * len(a)))) > 5 * near


def test_a_movement_much_smaller_than_the_target_is_no_repetition(bundled):
    """The target's own clip made smaller about its first pose (its joint angles' excursions
    scaled): at 0.8 of its size it is found, at 0.15 (a shift of weight, a step) it is not."""
    squat = _clips(bundled, "bd", "squat1Reps")[0]

    def smaller(k):
        return squat.with_data(squat.data[:1] + k * (squat.data - squat.data[:1]))

    for k, n in ((0.8, 3), (0.15, 0)):
        take, _ = join([smaller(k)] * 3, seed=4)
        found = seg.segment(take, squat, expected=3)
        assert len(found.repetitions) == n, (k, found.to_dict())


def test_the_persons_own_repetition_finds_the_others(bundled):
    """With a largest cost so low that only the repetition most like the target passes it, the
    person's own repetitions (``own``) find the others; without them only that one is found. The
    same settings cut nothing from a take of another motion."""
    from dataclasses import replace

    target = _clips(bundled, "bk", "squat1Reps")[0]
    others = [_clips(bundled, "dg", c)[0] for c in ("kickLFront1Reps", "elbowToKnee1RepsLelbowStart",
                                                    "rotateArmsBothBackward1Reps")]
    take, truth = join(_clips(bundled, "bd", "squat1Reps") * 2, seed=5)
    base = seg.segment(take, target, expected=4, background=others)
    assert len(base.repetitions) == 4
    lowest = min(r.cost for r in base.repetitions)
    tight = replace(seg.Settings(), max_cost=lowest + 1e-6, second_cost=lowest + 1e-6)
    alone = seg.segment(take, target, expected=4, background=others, settings=replace(tight, own=0.0))
    assert len(alone.repetitions) == 1
    own = seg.segment(take, target, expected=4, background=others, settings=replace(tight, own=1.5))
    assert score([(r.start, r.end) for r in own.repetitions], truth)["f1"] == 1.0, own.to_dict()
    kicks, _ = join(_clips(bundled, "bd", "kickLFront1Reps") * 2, seed=6)
    assert seg.segment(kicks, target, background=others, settings=replace(tight, own=1.5)).repetitions == []


def test_not_the_target_names_the_test_every_movement_failed(bundled):
    """"Not the target" says why: no movement long and large enough, the closest one too far
    from the target, or every one nearer to another motion; each with its numbers."""
    from dataclasses import replace

    target = _clips(bundled, "bk", "squat1Reps")[0]
    squats, _ = join(_clips(bundled, "bd", "squat1Reps") * 2, seed=9)
    far = seg.segment(squats, target, settings=replace(seg.Settings(), max_cost=0.05))
    assert far.repetitions == [] and far.closest is not None and far.closest > 0.05
    assert far.verdict.startswith(f"not the target: the movement most like it differs from it by {far.closest:.2f}")
    nearer = seg.segment(squats, target, background=[_clips(bundled, "bd", "squat1Reps")[0]],
                         settings=replace(seg.Settings(), own=0.0))
    assert nearer.repetitions == [] and nearer.refused is not None and nearer.refused > seg.COHORT
    assert nearer.verdict.startswith("not the target: every movement like it is nearer to another motion")
    still = squats.with_data(np.repeat(squats.data[:1], squats.n_frames, axis=0))
    nothing = seg.segment(still, target)
    assert nothing.closest is None and "no movement in the take is as long and as large" in nothing.verdict


def _space(bundled, performers):
    from shared.pss.space import ProtoSymbolSpace

    classes = ["elbowToKnee1RepsLelbowStart", "kickLFront1Reps", "rotateArmsBothBackward1Reps", "squat1Reps"]
    return ProtoSymbolSpace.build([c for p in performers for k in classes for c in _clips(bundled, p, k)], sensor=False)


def test_with_a_space_another_performers_kicks_are_found_and_other_motions_never_cut(bundled):
    """bk's kicks against bd's: the cohort check finds none (the closest stretch costs more than
    the cohort's largest first cost), a proto-symbol space of bd's and dg's motions names each of
    them a kick: every repetition found, each with the space's ratio below 1. bk's takes of the
    three other motions hold none against the kick, and the take of kicks none against bd's squat."""
    space = _space(bundled, ["bd", "dg"])
    target = _clips(bundled, "bd", "kickLFront1Reps")[0]
    take, truth = join(_clips(bundled, "bk", "kickLFront1Reps") * 2, seed=7)
    others = [_clips(bundled, "dg", o)[0] for o in ("elbowToKnee1RepsLelbowStart", "rotateArmsBothBackward1Reps", "squat1Reps")]
    cohort = seg.segment(take, target, expected=4, background=others)
    assert cohort.repetitions == [] and cohort.space is None and cohort.closest > seg.MAX_COST
    found = seg.segment(take, target, expected=4, space=space)
    assert score([(r.start, r.end) for r in found.repetitions], truth)["f1"] == 1.0, found.to_dict()
    assert found.space == "kickLFront1Reps" and all(r.cohort < 1.0 and 0.0 < r.confidence <= 1.0 for r in found.repetitions)
    for o in ("elbowToKnee1RepsLelbowStart", "rotateArmsBothBackward1Reps", "squat1Reps"):
        assert seg.segment(join(_clips(bundled, "bk", o) * 2, seed=8)[0], target, space=space).repetitions == [], o
    squat = seg.segment(take, _clips(bundled, "bd", "squat1Reps")[0], space=space)
    assert squat.repetitions == [] and squat.verdict.startswith("not the target")
    from dataclasses import replace

    anything = replace(seg.Settings(), space_cost=10.0, second_cost=10.0)  # the space alone decides
    squats = seg.segment(join(_clips(bundled, "bk", "squat1Reps") * 2, seed=8)[0], target, space=space, settings=anything)
    assert squats.repetitions == [] and squats.refused > 1.0
    assert squats.verdict.startswith("not the target: the space names every movement like it another motion than "
                                     "'kickLFront1Reps'")


def test_the_targets_motion_in_a_space_is_named_recognised_or_refused(bundled):
    """The target's label when the space holds it, else ``label``, else what the space recognises
    it as (said in a note); a label the space does not hold, a space with no other motion to tell
    it from, or one that models torques a take does not have, is refused in a sentence."""
    from dataclasses import replace

    space = _space(bundled, ["bk", "dg"])
    squat = _clips(bundled, "bd", "squat1Reps")[0]
    space = naming.SpaceNamer(space)
    assert naming.target_label(space, squat) == ("squat1Reps", None)
    unnamed = replace(squat, label=None)
    name, note = naming.target_label(space, unnamed)
    assert name == "squat1Reps" and "recognises the target as 'squat1Reps'" in note
    assert naming.target_label(space, unnamed, label="kickLFront1Reps") == ("kickLFront1Reps", None)
    with pytest.raises(BadInput, match="holds no motion 'jump'.*kickLFront1Reps"):
        naming.target_label(space, squat, label="jump")
    take, _ = join([squat] * 2, seed=1)
    from shared.bodies.arm import with_arm_torques
    from shared.pss.space import ProtoSymbolSpace

    classes = ["kickLFront1Reps", "squat1Reps"]
    felt = ProtoSymbolSpace.build([with_arm_torques(c) for k in classes for c in _clips(bundled, "bk", k)])
    with pytest.raises(BadInput, match="sensor channels a take from motion capture does not have .*motion clips alone"):
        seg.segment(take, squat, space=felt)  # it could recognise only clips with the arm's torques
    with pytest.raises(BadInput, match="at least one other"):
        seg.segment(take, squat, space=_space_of_one(bundled))
    assert seg.segment(take, unnamed, expected=2, space=space).notes == [note]


def test_a_space_with_one_example_of_the_target_leaves_it_to_the_other_motions_given(bundled):
    """A space that holds the target's motion once cannot tell how far a repetition may lie from
    it: given other motions too, the cohort check decides (said in a note, the same repetitions as
    without the space); given none, the space still decides."""
    from shared.pss.space import ProtoSymbolSpace

    others = ["elbowToKnee1RepsLelbowStart", "rotateArmsBothBackward1Reps", "squat1Reps"]
    target = _clips(bundled, "bd", "kickLFront1Reps")[0]
    space = ProtoSymbolSpace.build([target] + [c for o in others for c in _clips(bundled, "bd", o)], sensor=False)
    take, _ = join(_clips(bundled, "bk", "kickLFront1Reps") * 2, seed=7)
    background = [_clips(bundled, "dg", o)[0] for o in others]
    both = seg.segment(take, target, expected=4, background=background, space=space)
    cohort = seg.segment(take, target, expected=4, background=background)
    assert both.space is None and any("1 example of 'kickLFront1Reps'" in n for n in both.notes), both.notes
    assert [(r.start, r.end) for r in both.repetitions] == [(r.start, r.end) for r in cohort.repetitions]
    assert seg.segment(take, target, expected=4, space=space).space == "kickLFront1Reps"


def _space_of_one(bundled):
    from shared.pss.space import ProtoSymbolSpace

    return ProtoSymbolSpace.build(_clips(bundled, "bk", "squat1Reps") + _clips(bundled, "dg", "squat1Reps"), sensor=False)


def test_the_spaces_ratio_from_its_nearest_proto_symbols_alone():
    """From the nearest few proto-symbols (what the pss service replies): the target's nearest
    over the nearest other's; none of the target's listed: infinite (not named); no other listed:
    the farthest listed stands in (the true nearest other is farther still), so the ratio given is
    at least the true one and still below 1."""
    labels = np.array(["kick", "squat", "kick", "reach"])
    d = np.array([2.0, 4.0, 3.0, 5.0])
    assert naming.distance_ratio(labels, d, "kick") == pytest.approx(0.5)
    assert naming.distance_ratio(labels, d, "squat") == pytest.approx(2.0)
    assert naming.distance_ratio(labels, d, "jump") == np.inf
    assert naming.distance_ratio(np.array(["kick", "kick"]), np.array([1.0, 4.0]), "kick") == pytest.approx(0.25)


def test_scoring_a_long_takes_stretches_keeps_only_the_templates_it_returns():
    """A take of 100,000 frames has about 100,000 candidate stretches; their templates, all held
    until the cheapest were picked, took one segmentation to 5.6 GB. The same stretches scored
    keep no more than the ``MAX_CHECKS`` returned (tracemalloc counts numpy's bytes exactly)."""
    import tracemalloc

    r = np.random.default_rng(0)
    a = np.cumsum(r.normal(size=(30, 12)), axis=0)
    b = np.cumsum(r.normal(size=(4000, 12)), axis=0)
    stretches = {(s, s + 30) for s in range(0, 3960, 2)}  # 1,980 stretches of the target's length
    how = seg.Settings(min_amplitude=0.0)
    target = seg._Template(a, posture=how.posture)
    seg._score(a, b, {(0, 30)}, target, 1e-6, how)  # the compiled alignment loaded before counting
    tracemalloc.start()
    try:
        scored = seg._score(a, b, stretches, target, 1e-6, how)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert len(scored) == seg.MAX_CHECKS
    assert [x[:3] for x in scored] == sorted(x[:3] for x in scored)
    one = 30 * 12 * 8  # a stretch's shape, in bytes (its template holds about twice that)
    assert peak < 300 * one, peak  # 1,980 templates held together are over 2,000 shapes
