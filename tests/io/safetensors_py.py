"""Cross-check of the C safetensors code with an independent implementation
of the spec (json + struct + numpy; the safetensors package is not needed).
Run by test_safetensors_py.

usage: safetensors_py.py DIR
Checks c_model.safetensors, which the C test wrote (layout, values, and the
exact header bytes the Python library would write), then writes py_*.safetensors
for the C test to read: one valid file written the way other tools may
(unsorted, misaligned, escaped names, spaces) and a few it must refuse."""
import json
import struct
import sys

import numpy as np

DTYPES = {"F32": "<f4", "F16": "<f2", "I32": "<i4", "I64": "<i8", "U8": "u1", "F64": "<f8"}
# The Python library (its Rust core) orders tensors by dtype, larger
# elements first, then by name.
RANK = {"I64": 0, "F32": 1, "I32": 2, "F16": 3, "U8": 4}


def c_expected():
    """What test_safetensors_py.c writes (same formulas there)."""
    return {
        "layer.0.weight": np.arange(12, dtype=np.float32).reshape(3, 4) * 0.5 - 2.0,
        "layer.0.bias": np.array([1e-30, -3.5, 1e30], np.float32),
        "half": np.array([1.0, -0.5, 65504.0, 0.0], np.float16),
        "ids": np.array([-7, 0, 1 << 40], np.int64),
        "step": np.array(12345, np.int32),
        "mask": np.array([[0, 255, 3], [4, 5, 6]], np.uint8),
        "none": np.zeros((0, 7), np.float32),
        "caf\u00e9 \"q\"\n": np.array([9], np.uint8),
    }


C_META = {"format": "gazesplat", "version": "1", "config": "{\"size\": [64, 64]}\u00e9\t"}


def read_spec(path):
    """Parses a file by the spec; returns header dict, metadata, arrays."""
    raw = open(path, "rb").read()
    (n,) = struct.unpack("<Q", raw[:8])
    header = json.loads(raw[8:8 + n].decode("utf-8"))
    buf = raw[8 + n:]
    meta = header.pop("__metadata__", None)
    arrays, spans = {}, []
    for name, info in header.items():
        b, e = info["data_offsets"]
        arrays[name] = np.frombuffer(buf[b:e], dtype=DTYPES[info["dtype"]]).reshape(info["shape"])
        spans.append((b, e))
    spans.sort()
    at = 0
    for b, e in spans:
        assert b == at, f"hole or overlap at {b} (expected {at})"
        at = e
    assert at == len(buf), f"buffer {len(buf)} bytes, tensors cover {at}"
    return raw, n, header, meta, arrays


def python_library_header(header, meta):
    """The header bytes the Python library writes for these entries."""
    order = sorted(header, key=lambda k: (RANK[header[k]["dtype"]], k.encode()))
    d = {}
    if meta:
        d["__metadata__"] = {k: meta[k] for k in sorted(meta, key=str.encode)}
    for k in order:
        d[k] = header[k]
    s = json.dumps(d, separators=(",", ":"), ensure_ascii=False).encode()
    return s + b" " * (-len(s) % 8)


def check_c_file(d):
    bad = 0
    raw, n, header, meta, arrays = read_spec(f"{d}/c_model.safetensors")
    want = c_expected()
    if set(arrays) != set(want):
        print(f"c_model: names {sorted(arrays)}, want {sorted(want)}")
        return 1
    for name, w in want.items():
        g = arrays[name]
        if g.dtype != w.dtype or g.shape != w.shape or not np.array_equal(g, w):
            print(f"c_model[{name!r}]: got {g.dtype} {g.shape} {g.ravel()[:4]}, "
                  f"want {w.dtype} {w.shape} {w.ravel()[:4]}")
            bad += 1
    if meta != C_META:
        print(f"c_model metadata {meta}, want {C_META}")
        bad += 1
    if n % 8:
        print(f"c_model: header length {n} not a multiple of 8")
        bad += 1
    ref = python_library_header(header, meta)
    if raw[8:8 + n] != ref:
        print(f"c_model header:\n  {raw[8:8 + n]!r}\nthe Python library would write:\n  {ref!r}")
        bad += 1
    return bad


def write_spec(path, entries, meta=None, dumps=json.dumps, pad=True, order=None):
    """entries: name -> (dtype, array, or raw bytes). Data in the given order
    (no alignment), header with Python's default json.dumps (spaces,
    ASCII escapes)."""
    header, chunks, at = {}, [], 0
    if meta is not None:
        header["__metadata__"] = meta
    for name in order or entries:
        dt, arr = entries[name]
        data = arr if isinstance(arr, bytes) else np.ascontiguousarray(arr, DTYPES[dt]).tobytes()
        shape = [len(data) // np.dtype(DTYPES[dt]).itemsize] if isinstance(arr, bytes) else list(arr.shape)
        header[name] = {"shape": shape, "dtype": dt, "data_offsets": [at, at + len(data)]}
        chunks.append(data)
        at += len(data)
    h = dumps(header).encode()
    if pad:
        h += b" " * (-len(h) % 8 + 5)
    with open(path, "wb") as f:
        f.write(struct.pack("<Q", len(h)) + h + b"".join(chunks))


def py_model():
    """What test_safetensors_py.c checks in py_model.safetensors."""
    return {
        "u8": ("U8", np.array([1, 2, 3], np.uint8)),
        "weight": ("F32", np.arange(6, dtype=np.float32).reshape(2, 3) * 0.25 - 1.0),
        "idx": ("I64", np.array([-5, 0, 7, 1 << 40], np.int64)),
        "half": ("F16", np.array([1.0, -0.5, 65504.0], np.float16)),
        "count": ("I32", np.array(42, np.int32)),
        "caf\u00e9 \U0001F600": ("F32", np.array([3.5], np.float32)),
        "empty": ("F32", np.zeros((0, 3), np.float32)),
    }


def write_py_files(d):
    write_spec(f"{d}/py_model.safetensors", py_model(), meta={"format": "py", "note": "\u00e9\n"})
    # Refused: NaN, F64, a hole, overlapping tensors, a float in a shape.
    write_spec(f"{d}/py_nan.safetensors", {"x": ("F32", np.array([0.0, np.nan], np.float32))})
    write_spec(f"{d}/py_f64.safetensors", {"x": ("F64", np.zeros(2))})
    hole = json.dumps({"a": {"dtype": "U8", "shape": [2], "data_offsets": [0, 2]},
                       "b": {"dtype": "U8", "shape": [2], "data_offsets": [4, 6]}}).encode()
    with open(f"{d}/py_hole.safetensors", "wb") as f:
        f.write(struct.pack("<Q", len(hole)) + hole + bytes(6))
    over = json.dumps({"a": {"dtype": "U8", "shape": [4], "data_offsets": [0, 4]},
                       "b": {"dtype": "U8", "shape": [4], "data_offsets": [2, 6]}}).encode()
    with open(f"{d}/py_overlap.safetensors", "wb") as f:
        f.write(struct.pack("<Q", len(over)) + over + bytes(6))
    flt = b'{"a": {"dtype": "U8", "shape": [2.0], "data_offsets": [0, 2]}}'
    with open(f"{d}/py_float_shape.safetensors", "wb") as f:
        f.write(struct.pack("<Q", len(flt)) + flt + bytes(2))


def main(d):
    bad = check_c_file(d)
    write_py_files(d)
    # Our own reader accepts what we wrote.
    read_spec(f"{d}/py_model.safetensors")
    print(f"safetensors_py: {bad} problems")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1]))
