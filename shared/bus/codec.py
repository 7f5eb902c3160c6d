"""The wire format: msgpack maps, numpy arrays as ``{"__nd__": true, dtype, shape, data}``.

No pickle, no object arrays: an array travels as its raw little-endian bytes with a dtype from
a fixed list, and is decoded read-only (``np.frombuffer``) without a copy. Incoming payloads
are size-checked before they are parsed.
"""

from __future__ import annotations

import math
import sys

import msgpack

from shared.errors import BadInput

#: dtypes an array may have on the wire (little-endian); anything else is refused.
WIRE_DTYPES = {"<f8", "<f4", "<i8", "<i4", "<i2", "|i1", "<u8", "<u4", "<u2", "|u1", "|b1"}

#: default limit on an incoming payload, bytes (MIRRORCOACH_MAX_PAYLOAD overrides it in services)
DEFAULT_MAX_PAYLOAD = 64 * 1024 * 1024


def _default(obj):
    np = sys.modules.get("numpy")  # not imported: no array can be here (the CLI starts without numpy)
    if np is None:
        raise TypeError(f"cannot encode {type(obj).__name__}")
    if isinstance(obj, np.ndarray):
        a = obj
        if a.dtype.kind not in "fiub":
            raise BadInput(f"cannot send an array of dtype {a.dtype} (numbers and booleans only)")
        a = np.ascontiguousarray(a, dtype=a.dtype.newbyteorder("<"))
        return {"__nd__": True, "dtype": a.dtype.str, "shape": list(a.shape), "data": a.tobytes()}
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, (set, frozenset)):
        return sorted(obj)
    raise TypeError(f"cannot encode {type(obj).__name__}")


def _array_header(d: dict, itemsize) -> tuple[str, list, bytes]:
    """An array message's dtype, shape and data, checked (``itemsize(dtype)``: its item's bytes)."""
    dtype, shape, data = d.get("dtype"), d.get("shape"), d.get("data")
    if dtype not in WIRE_DTYPES:
        raise BadInput(f"array dtype {dtype!r} is not accepted (one of {sorted(WIRE_DTYPES)})")
    if not (isinstance(shape, list) and all(isinstance(n, int) and n >= 0 for n in shape)) or len(shape) > 8:
        raise BadInput(f"array shape {shape!r} is not a list of at most 8 non-negative integers")
    if not isinstance(data, bytes):
        raise BadInput("array data must be bytes")
    if len(data) != math.prod(shape) * itemsize(dtype):
        raise BadInput(f"array data has {len(data)} bytes, shape {shape} of {dtype} needs {math.prod(shape) * itemsize(dtype)}")
    return dtype, shape, data


def _decode_array(d: dict):
    import numpy as np

    dtype, shape, data = _array_header(d, lambda t: np.dtype(t).itemsize)
    return np.frombuffer(data, dtype=np.dtype(dtype)).reshape(shape)


def _object_hook(d: dict):
    if d.get("__nd__") is True:
        return _decode_array(d)
    return d


#: wire dtypes as the standard library's ``array`` type codes (for :func:`unpack` with ``arrays="lists"``)
_ARRAY_CODES = {"<f8": "d", "<f4": "f", "<i8": "q", "<i4": "i", "<i2": "h", "|i1": "b", "<u8": "Q", "<u4": "I",
                "<u2": "H", "|u1": "B", "|b1": "B"}


def _array_as_lists(d: dict):
    """An array message as nested Python lists, without numpy (the same checks as the array path)."""
    if d.get("__nd__") is not True:
        return d
    import array

    dtype, shape, data = _array_header(d, lambda t: array.array(_ARRAY_CODES[t]).itemsize)
    a = array.array(_ARRAY_CODES[dtype])
    a.frombytes(data)
    if sys.byteorder == "big" and a.itemsize > 1:
        a.byteswap()
    flat: list = [bool(v) for v in a] if dtype == "|b1" else a.tolist()
    for n in reversed(shape[1:]):
        flat = [flat[i:i + n] for i in range(0, len(flat), n)]
    return flat if shape else (flat[0] if flat else None)


def pack(obj) -> bytes:
    """Encode a message (maps, lists, strings, numbers, numpy arrays) as msgpack bytes."""
    return msgpack.packb(obj, default=_default, use_bin_type=True)


def unpack(payload: bytes, max_size: int = DEFAULT_MAX_PAYLOAD, arrays: str = "numpy"):
    """Decode msgpack bytes; arrays come back read-only (``arrays="lists"``: as nested lists,
    without importing numpy). Raises :class:`BadInput` on anything that is not a well-formed
    message within ``max_size`` bytes."""
    if len(payload) > max_size:
        raise BadInput(f"payload of {len(payload)} bytes is over the limit of {max_size} bytes",
                       size=len(payload), limit=max_size)
    try:
        return msgpack.unpackb(payload, object_hook=_object_hook if arrays == "numpy" else _array_as_lists, raw=False, strict_map_key=True,
                               max_bin_len=max_size, max_str_len=max_size)
    except BadInput:
        raise
    except Exception as e:  # msgpack raises several types (ExtraData, FormatError, ValueError, ...)
        raise BadInput(f"payload is not valid msgpack ({type(e).__name__}: {e})") from None
