"""``make bench``: malformed requests on every verb of every contract, through a real cluster.

Each request is invalid (the contract refuses it, checked before sending), made from the verb's
own contract (``schemas/``): one field at a time missing, of the wrong type, out of range, not
finite, too long, nested 10,000 deep or 100,000 deep; and for the whole message: not a map,
not msgpack, an unknown field, a schema version from the future, an empty payload. Sent raw (no client-side check), a few
clients at once, over rounds until ``--requests`` have gone out.

What is counted: the code of every answer (``bad_request`` expected; ``internal`` is a bug; no
answer at all is a hang), the cluster's state (every service's ``list``) before and after (a
refused request must change nothing), and the resident memory of every process after each
round (the observer draws every request's latency: it must stay flat).

Writes ``bench/results/fuzz.json`` and ``bench/results/fuzz.md``.
"""

from __future__ import annotations

import json
import math
import time
from collections import Counter
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from bench.common import parse_args, private_cluster, write_results
from bench.memory import cluster_pids, rss_mb

LIST_VERBS = {"pss": "list", "simulator": "list", "estimator": "list", "coach": "list", "capture": "list",
              "dialogue": "list"}


def example(spec):
    """A plausible value for ``spec`` (the seed a mutation changes one field of)."""
    from schemas import base as b

    if isinstance(spec, b.Str):
        return spec.choices[0] if spec.choices else "fuzz1"
    if isinstance(spec, b.Int):
        return spec.min if spec.min is not None else 1
    if isinstance(spec, b.Float):
        return float(spec.min) if spec.min is not None else 1.0
    if isinstance(spec, b.Bool):
        return False
    if isinstance(spec, b.Bytes):
        return b"x"
    if isinstance(spec, b.Array):
        shape = [n if n is not None else max(2, (spec.min_shape or [0] * len(spec.shape))[i])
                 for i, n in enumerate(spec.shape)]
        return np.zeros(shape, dtype=bool if spec.kind == "b" else (np.int64 if spec.kind == "i" else np.float64))
    if isinstance(spec, b.List):
        return [example(spec.item) for _ in range(max(1, spec.min_len))]
    if isinstance(spec, b.Map):
        return {k: example(f.spec) for k, f in spec.fields.items() if f.required}
    return {}


DEEP = "__DEEP__"  # packed, then replaced by a list nested n deep (msgpack's packer stops at 512 levels)


def with_deep(payload: bytes, n: int) -> bytes:
    """``payload`` with the packed string ``DEEP`` replaced by a list nested ``n`` deep."""
    from shared.bus.codec import pack

    return payload.replace(pack(DEEP), b"\x91" * n + b"\x90")


BAD_VALUES = [None, "text", 7, -1, 2**62, 1.5, math.nan, math.inf, -1e308, True, b"\x00\xff", [], {}, [[1, 2], [3]],
              {"a": 1}, "x" * 100_000, np.full((3, 3), np.nan), np.zeros((2, 2, 2, 2)), np.array([1, 2], dtype=np.int8)]


def paths(spec, prefix=()):
    """Every field path of a map spec (into nested maps and a list's first map)."""
    from schemas import base as b

    if isinstance(spec, b.Map):
        for k, f in spec.fields.items():
            yield prefix + (k,), f
            inner = f.spec.item if isinstance(f.spec, b.List) else f.spec
            if isinstance(inner, b.Map):
                yield from paths(inner, prefix + ((k, 0) if isinstance(f.spec, b.List) else (k,)))


def set_path(msg: dict, path: tuple, value, delete: bool = False) -> dict:
    """A copy of ``msg`` with ``path`` set to ``value`` (or deleted)."""
    import copy

    out = copy.deepcopy(msg)
    cur = out
    flat = [p for step in path for p in (step if isinstance(step, tuple) else (step,))]
    for step in flat[:-1]:
        if isinstance(cur, dict):
            cur = cur.setdefault(step, {})
        elif isinstance(cur, list) and isinstance(step, int) and step < len(cur):
            cur = cur[step]
        else:
            return out
    last = flat[-1]
    if isinstance(cur, dict):
        if delete:
            cur.pop(last, None)
        else:
            cur[last] = value
    return out


def refused(endpoint, payload: bytes) -> bool:
    """Whether the contract itself refuses ``payload`` (a mutation can happen to be valid: a value
    in range for a field without bounds; those are not sent)."""
    from shared.bus.codec import unpack
    from shared.errors import MirrorcoachError

    try:
        endpoint.request.validate(unpack(payload) if payload else {})
    except (MirrorcoachError, RecursionError, ValueError):
        return True
    return False


def mutations(endpoint):
    """Invalid requests for one verb (payload bytes), made from its contract and each refused by it."""
    from shared.bus.codec import pack

    body = endpoint.request.body
    seed = example(body)
    raw = [b"", b"\xc1\xc1\xc1", b"not msgpack at all", pack([1, 2, 3]), pack("a map? no"), pack({"v": 99, **seed}),
           pack({**seed, "unexpected_field": 1}), pack({1: 2}), with_deep(pack(DEEP), 10_000),
           with_deep(pack({"v": 1, "x": DEEP}), 100_000)]
    out = list(raw)
    for path, f in paths(body):
        if f.required:
            out.append(pack(set_path(seed, path, None, delete=True)))
        for bad in BAD_VALUES if f.required else [v for v in BAD_VALUES if v is not None]:
            try:
                out.append(pack(set_path(seed, path, bad)))
            except Exception:  # a value our codec refuses to pack is not sent
                pass
        out.append(with_deep(pack(set_path(seed, path, DEEP)), 10_000))
    return [p for p in out if refused(endpoint, p)]


def state(c) -> dict:
    """Every service's list: what a refused request must leave unchanged."""
    from shared.bus.client import RemoteError, Unavailable

    snap = {}
    for service, verb in LIST_VERBS.items():
        try:
            snap[service] = json.loads(json.dumps(c.request_raw(service, verb, b"\x80", timeout=30), default=str,
                                                  sort_keys=True))
        except (RemoteError, Unavailable) as e:
            snap[service] = f"error: {e}"
    return snap


def main(argv=None) -> int:
    def extra(ap):
        ap.add_argument("--requests", type=int, default=30_000, help="malformed requests in all")
        ap.add_argument("--clients", type=int, default=4)

    args = parse_args(__doc__, argv, extra=extra)
    from schemas import CONTRACTS
    from schemas.common import clip_to_wire
    from shared.bus.client import Client, RemoteError, Unavailable
    from shared.io import find_clips, load_clip

    cases = [(service, verb, payload) for service, contract in sorted(CONTRACTS.items())
             for verb, ep in sorted(contract.ENDPOINTS.items()) for payload in mutations(ep)]
    np.random.default_rng(0).shuffle(cases)  # every round of the same length covers every verb
    print(f"{len(cases)} distinct malformed requests on {len({(s, v) for s, v, _ in cases})} verbs")
    clips = [load_clip(f).resample(30) for f in find_clips([args.hdm05 / "amc"])[:4]]
    codes: Counter = Counter()
    by_verb: dict[str, Counter] = {}
    internal: list[str] = []
    res: dict = {"requests": 0, "rounds": []}
    with private_cluster("fuzz") as s, Client(s) as c:
        c.request("pss", "build", {"space": "fuzz", "clips": [clip_to_wire(x) for x in clips]})  # state to keep
        c.request("coach", "start", {"session": "fuzz", "learner": "fuzz", "target": clip_to_wire(clips[0])},
                  timeout=120)
        time.sleep(2.0)
        before = state(c)
        res["rss_start_mb"] = {n: rss_mb(p) for n, p in cluster_pids(s).items()}

        def one(case):
            service, verb, payload = case
            try:
                c.request_raw(service, verb, payload, timeout=30)
                return service, verb, "ok"
            except RemoteError as e:
                if e.code == "internal":
                    internal.append(f"{service}/{verb}: {e.message[:200]}")
                return service, verb, e.code
            except Unavailable as e:
                return service, verb, "no answer" if "no answer" in str(e) or "timed out" in str(e) else "unavailable"
            except Exception as e:  # noqa: BLE001 - a client-side refusal (payload too large) is counted, not fatal
                return service, verb, f"client: {type(e).__name__}"

        t0 = time.perf_counter()
        with ThreadPoolExecutor(args.clients) as pool:
            while res["requests"] < args.requests:
                batch = cases[: args.requests - res["requests"]]
                for service, verb, code in pool.map(one, batch):
                    codes[code] += 1
                    by_verb.setdefault(f"{service}/{verb}", Counter())[code] += 1
                res["requests"] += len(batch)
                time.sleep(1.0)  # the observer catches up before it is measured
                row = {"requests": res["requests"], "seconds": time.perf_counter() - t0,
                       "rss_mb": {n: rss_mb(p) for n, p in cluster_pids(s).items()}}
                res["rounds"].append(row)
                print(f"{row['requests']} requests in {row['seconds']:.0f} s: {dict(codes)}; observer "
                      f"{row['rss_mb'].get('observer', 0):.0f} MB")
        time.sleep(2.0)
        after = state(c)
    changed = sorted(k for k in before if before[k] != after[k])
    res.update(codes=dict(codes), internal=internal[:50], changed=changed,
               by_verb={k: dict(v) for k, v in sorted(by_verb.items())}, distinct=len(cases))
    first, last = res["rounds"][0]["rss_mb"], res["rounds"][-1]["rss_mb"]
    growth = {n: last[n] / first[n] - 1 for n in first if n in last and first[n]}
    res["growth_after_first_round"] = growth
    ok = {"internal": codes.get("internal", 0) == 0, "state": not changed,
          "answered": codes.get("no answer", 0) == 0, "observer": growth.get("observer", 0) <= 0.10}
    res["goals"] = ok
    md = ["# Malformed requests through a real cluster", "",
          f"`python -m bench.fuzz`: {res['requests']} requests ({len(cases)} distinct, made from the contracts of "
          f"{len(by_verb)} verbs: one field at a time missing, mistyped, out of range, not finite, too long or "
          f"nested 10,000 deep; whole messages not a map, not msgpack, nested 100,000 deep, from a future "
          f"version), {args.clients} clients at once.", "",
          "| answer | requests |", "|---|---|"]
    md += [f"| {k} | {v} |" for k, v in codes.most_common()]
    state_words = "unchanged" if not changed else "CHANGED: " + ", ".join(changed)
    md += ["", f"State (every service's list) before and after: {state_words}.",
           "", "Resident memory after each round of the distinct requests (MB):", "",
           "| requests | " + " | ".join(first) + " |", "|---|" + "---|" * len(first)]
    md += [f"| {r['requests']} | " + " | ".join(f"{r['rss_mb'].get(n, 0):.0f}" for n in first) + " |"
           for r in res["rounds"]]
    md += ["", "Growth from the first round to the last: "
           + ", ".join(f"{n} {100 * g:+.1f} %" for n, g in growth.items()),
           "", "An `ok` or `not_found` answer is a request that turned out valid (an empty payload is an empty map; "
               "an optional field sent as nil takes its default) about something that does not exist.",
           "", "Goals: 0 `internal` " + ("met" if ok["internal"] else f"missed ({codes['internal']})")
           + "; 0 state changes " + ("met" if ok["state"] else "missed")
           + "; every request answered " + ("met" if ok["answered"] else "missed")
           + "; observer within 10 % after the first round " + ("met" if ok["observer"] else "missed") + "."]
    if internal:
        md += ["", "First `internal` answers:", ""] + [f"- {x}" for x in internal[:10]]
    write_results(args.out, "fuzz", res, md)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
