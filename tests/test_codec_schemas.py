"""The wire format, the contracts and the bus settings, without a bus."""

from __future__ import annotations

import os

import msgpack
import numpy as np
import pytest

from schemas import CONTRACTS
from schemas.common import clip_from_wire, clip_to_wire
from schemas.pss import BUILD, GENERATE, RECOGNIZE
from shared.bus.codec import pack, unpack
from shared.bus.config import Settings, check_loopback
from shared.errors import BadInput


def _clip(frames=30, channels=3, **kw):
    d = {"name": "c1", "label": "squat", "fps": 30.0, "channels": [f"j{i}.rx" for i in range(channels)],
         "data": np.zeros((frames, channels))}
    d.update(kw)
    return d


def test_codec_round_trip_keeps_dtype_shape_and_is_read_only():
    msg = {"a": np.arange(12, dtype=np.float64).reshape(3, 4), "b": np.array([1, 2], dtype=np.int32),
           "c": np.array([True, False]), "s": "x", "n": [1, 2.5, None], "g": np.float32(1.5)}
    out = unpack(pack(msg))
    for k in "abc":
        assert out[k].dtype == msg[k].dtype and out[k].shape == msg[k].shape and np.array_equal(out[k], msg[k])
        assert not out[k].flags.writeable
    assert out["s"] == "x" and out["n"] == [1, 2.5, None] and out["g"] == 1.5
    big_endian = np.arange(5, dtype=">f8")
    assert np.array_equal(unpack(pack({"x": big_endian}))["x"], big_endian)


@pytest.mark.parametrize("payload, match", [
    (b"\xc1\x00\x01", "not valid msgpack"),
    (msgpack.packb({"__nd__": True, "dtype": "|O", "shape": [1], "data": b"x"}), "dtype"),
    (msgpack.packb({"__nd__": True, "dtype": "<f8", "shape": [3], "data": b"\x00" * 16}), "needs 24"),
    (msgpack.packb({"__nd__": True, "dtype": "<f8", "shape": [-1], "data": b""}), "shape"),
    (b"\x01" * 20, "not valid msgpack"),  # trailing data
])
def test_codec_refuses_malformed_payloads(payload, match):
    with pytest.raises(BadInput, match=match):
        unpack(payload)


def test_codec_size_limit_is_checked_before_parsing():
    with pytest.raises(BadInput, match="over the limit") as e:
        unpack(pack({"x": np.zeros(1000)}), max_size=1000)
    assert e.value.details["limit"] == 1000
    with pytest.raises(BadInput, match="object"):
        pack({"x": np.array(["a"], dtype=object)})


def test_contract_fills_defaults_and_converts_int_arrays():
    req = BUILD.request.validate({"space": "s1", "clips": [_clip(data=np.zeros((30, 3), dtype=np.int64))]})
    assert req["dim"] == 3 and req["replace"] is False and req["n_states"] is None
    assert req["clips"][0]["data"].dtype == np.float64 and req["clips"][0]["sensor"] == []


@pytest.mark.parametrize("change, field", [
    ({"space": "../etc"}, "space"), ({"space": "a/b"}, "space"), ({"space": ".hidden"}, "space"),
    ({"clips": []}, "clips"), ({"clips": [_clip(frames=1)]}, "clips[0].data"),
    ({"clips": [_clip(frames=0)]}, "clips[0].data"),
    ({"clips": [_clip(data=np.full((30, 3), np.nan))]}, "clips[0].data"),
    ({"clips": [_clip(data=np.zeros((30, 4)))]}, "clips[0].data"),
    ({"clips": [_clip(fps=float("inf"))]}, "clips[0].fps"),
    ({"clips": [_clip(fps="30")]}, "clips[0].fps"),
    ({"clips": [_clip(channels=2, data=np.zeros((30, 2)), sensor=["tau.x"])]}, "clips[0].sensor"),
    ({"dim": 0}, "dim"), ({"dim": True}, "dim"), ({"extra": 1}, ""), ({"v": 2}, "v"),
])
def test_contract_names_the_bad_field(change, field):
    msg = {"space": "s1", "clips": [_clip()], **change}
    with pytest.raises(BadInput) as e:
        BUILD.request.validate(msg)
    assert e.value.details["field"] == field, e.value.message


def test_generate_needs_exactly_one_of_point_and_mix():
    with pytest.raises(BadInput, match="exactly one"):
        GENERATE.request.validate({"space": "s"})
    with pytest.raises(BadInput, match="exactly one"):
        GENERATE.request.validate({"space": "s", "point": np.zeros(3), "mix": {"a": 1.0}})
    assert GENERATE.request.validate({"space": "s", "mix": {"a": 1.0}})["method"] == "expected"


def test_every_contract_is_readable_and_complete():
    for name, mod in CONTRACTS.items():
        assert mod.ENDPOINTS, name
        for verb, ep in mod.ENDPOINTS.items():
            text = ep.request.describe() + ep.reply.describe()
            assert ep.verb == verb and ep.doc and f"{name}.{verb}" in text
    assert "space: string matching" in RECOGNIZE.request.describe()


def test_clip_wire_round_trip(bundled):
    from shared.io import load_clip

    c = load_clip(bundled / "amc/squat1Reps/HDM_bd_squat1Reps_001_120.amc")
    back = clip_from_wire(unpack(pack(clip_to_wire(c))))
    assert back.channels == c.channels and back.fps == c.fps and back.label == c.label
    assert np.array_equal(back.data, c.data) and back.skeleton == c.skeleton
    with pytest.raises(BadInput, match="skeleton"):
        clip_from_wire({**clip_to_wire(c), "skeleton": "{not json"})
    with pytest.raises(BadInput, match="nests too deeply"):  # not a RecursionError reported as internal
        clip_from_wire({**clip_to_wire(c), "skeleton": "[" * 100_000 + "]" * 100_000})


def test_settings_accept_loopback_only():
    assert check_loopback("tcp/127.0.0.1:7447") and check_loopback("tcp/[::1]:7447") and check_loopback("tcp/localhost:1")
    for bad in ("tcp/0.0.0.0:7447", "tcp/192.168.1.4:7447", "tcp/example.com:7447", "7447", "tcp/127.0.0.1:70000"):
        with pytest.raises(BadInput):
            check_loopback(bad)
    for bad in ("unixsock-stream/relative.sock", "unixsock-stream//" + "x" * 200):
        with pytest.raises(BadInput, match="absolute path"):
            check_loopback(bad)
    with pytest.raises(BadInput, match="PREFIX"):
        Settings(prefix="a/b")


def test_the_default_router_is_a_socket_in_the_home_or_a_short_one_of_the_user(tmp_path):
    """Without MIRRORCOACH_ROUTER the cluster listens on its home's socket; a home too deep for
    a socket path gets one in /tmp/mirrorcoach-<uid>, a different one per home."""
    from shared.bus.config import default_router

    assert Settings(router="", home=tmp_path).router == f"unixsock-stream/{tmp_path}/run/router.sock"
    deep, other = tmp_path / ("d" * 60) / ("e" * 60), tmp_path / ("d" * 60) / ("f" * 60)
    r = default_router(deep)
    assert r.startswith(f"unixsock-stream//tmp/mirrorcoach-{os.getuid()}/") and r != default_router(other)
    assert check_loopback(r) == r
    assert Settings(prefix="mc2").key("pss", "build") == "mc2/pss/build"


def test_every_request_with_bytes_field_names_is_bad_input_not_internal():
    """msgpack keeps bytes keys as bytes; a map mixing them with text must be refused as bad
    input by every endpoint's contract, not crash while listing the fields."""
    msg = unpack(msgpack.packb({b"a": 1, "b": 2}))
    checked = 0
    for contract in CONTRACTS.values():
        for ep in contract.ENDPOINTS.values():
            with pytest.raises(BadInput, match="field names must be text"):
                ep.request.validate(msg)
            checked += 1
    assert checked >= 40  # every request key of the five services


def test_arrays_decode_to_lists_without_numpy_alike():
    a = np.arange(12, dtype="<f8").reshape(3, 4) / 7
    back = unpack(pack({"x": a, "b": np.array([True, False]), "i": np.array([-3, 5], dtype="<i2")}), arrays="lists")
    assert back["x"] == a.tolist() and back["b"] == [True, False] and back["i"] == [-3, 5]
    with pytest.raises(BadInput):
        unpack(pack({"__nd__": True, "dtype": "<f8", "shape": [2], "data": b"\x00" * 8}), arrays="lists")


def test_a_message_names_its_unknown_field_bad_name_and_non_finite_number():
    """The checks kept on the fast path (the fields' names as a set, patterns compiled once,
    finiteness of a plain float): each bad message names the field and the reason."""
    from schemas import dialogue

    spec = dialogue.EVENTS["transcript"]
    good = {"t": 1, "dialogue": "ch3-mass-1", "speaker": "self", "kind": "question", "text": "how heavy?"}
    assert spec.validate(good)["t"] == 1.0 and isinstance(spec.validate(good)["t"], float)
    with pytest.raises(BadInput, match=r"unknown field\(s\) colour, size; expected t, dialogue"):
        spec.validate({**good, "size": 3, "colour": "red"})
    with pytest.raises(BadInput, match="dialogue: '../x' is not a valid name"):
        spec.validate({**good, "dialogue": "../x"})
    for bad in (float("nan"), float("inf"), 10 ** 400):
        with pytest.raises(BadInput, match="t: must be finite"):
            spec.validate({**good, "t": bad})
