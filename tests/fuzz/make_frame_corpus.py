"""Writes the seed corpus of fuzz_frame (corpus/frame/): streams of frames
as a client or server would send them, with a hand-rolled protobuf encoder
(standard library only). The first byte of each file is the fuzz target's
mode byte (limits and chunk size). Deterministic; rerun after changing it:
    python3 tests/fuzz/make_frame_corpus.py tests/fuzz/corpus/frame"""
import os
import struct
import sys


def varint(v):
    out = b""
    while True:
        b = v & 0x7F
        v >>= 7
        if v:
            out += bytes([b | 0x80])
        else:
            return out + bytes([b])


def f_varint(field, v):
    return varint(field << 3) + varint(v)


def f_bytes(field, b):
    return varint(field << 3 | 2) + varint(len(b)) + b


def f_double(field, x):
    return varint(field << 3 | 1) + struct.pack("<d", x)


def frame(ftype, body=b"", rid=1, key=b"\0" * 16, version=1, magic=b"GAZE", length=None):
    n = len(body) if length is None else length
    return struct.pack("<4sHHI16sI", magic, version, ftype, n, key, rid) + body


def angles(p, y):
    return f_double(1, p) + f_double(2, y)


def main(out):
    os.makedirs(out, exist_ok=True)
    hello = frame(1, f_varint(1, 1) + f_varint(2, 1) + f_bytes(3, b"fuzz") + f_bytes(4, b"tok"))
    raw = f_varint(1, 3) + f_bytes(2, bytes(range(12))) + f_varint(3, 2) + f_varint(4, 2) + f_varint(5, 6)
    fit = frame(7, f_bytes(1, raw) + f_bytes(2, angles(5.0, -3.0)) + f_bytes(3, angles(0.0, 10.0)) +
                f_bytes(4, f_double(1, 800) + f_double(2, 800) + f_double(3, 128) + f_double(4, 128)) +
                f_varint(5, 1000) + f_varint(6, 50), rid=2)
    target = f_bytes(1, angles(10.0, -20.0)) + f_bytes(2, angles(0.0, 5.0))
    redirect = frame(9, f_bytes(2, target) + f_bytes(2, f_bytes(1, angles(0.0, 15.0))) +
                     f_varint(3, 2) + f_varint(4, 90) + f_varint(6, 500), rid=3, key=bytes(range(16)))
    seeds = {
        "hello": b"\x01" + hello,
        "session": b"\x00" + hello + frame(3, rid=2) + frame(5, rid=3) + fit + redirect +
                   frame(12, f_varint(1, 3), rid=4),
        "session_chunk7": b"\x18" + hello + fit + redirect,
        "replies": b"\x02" + frame(2, f_varint(1, 1) + f_bytes(2, b"gazesplatd") +
                                   f_bytes(3, f_varint(1, 1 << 20) + f_varint(2, 64))) +
                   frame(13, f_varint(1, 18) + f_bytes(2, b"no subject") + f_varint(3, 7), rid=7) +
                   frame(14, f_varint(1, 250) + f_varint(2, 16), rid=9) +
                   frame(10, f_varint(1, 0) + f_bytes(2, raw) + f_bytes(3, target), rid=3) +
                   frame(11, f_varint(1, 1) + f_double(2, 0.5), rid=3) +
                   frame(6, f_bytes(1, f_bytes(1, b"fits") + f_varint(2, 3))),
        "bad_magic": b"\x00" + frame(1, magic=b"GAZF"),
        "bad_version": b"\x00" + frame(1, version=2),
        "bad_type": b"\x00" + frame(999),
        "too_large": b"\x01" + frame(1, length=4097),
        "huge": b"\x00" + frame(9, length=0xFFFFFFFF),
        "truncated": b"\x00" + hello[:-3],
        "garbage_body": b"\x00" + frame(7, b"\xff\xff\xff\xff\x0f\x0a\x40"),
        "nan_angles": b"\x00" + frame(9, f_bytes(2, f_bytes(1, f_double(1, float("nan")) +
                                                              f_double(2, float("inf"))))),
    }
    for name, data in seeds.items():
        with open(os.path.join(out, name), "wb") as f:
            f.write(data)


if __name__ == "__main__":
    main(sys.argv[1])
