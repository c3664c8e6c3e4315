"""Writes the seed corpora of the fuzz targets (corpus/<target>/): small
valid inputs of each layout and a few damaged ones. Deterministic, standard
library only; rerun after changing it:
    python3 tests/fuzz/make_corpus.py tests/fuzz/corpus"""
import json
import os
import struct
import sys
import zlib


def header(n, props, fmt="binary_little_endian 1.0", extra="", eol="\n"):
    lines = ["ply", f"format {fmt}"] + ([extra] if extra else [])
    lines += [f"element vertex {n}"] + [f"property {t} {p}" for t, p in props]
    lines += ["end_header"]
    return (eol.join(lines) + eol).encode()


def std_props(rest=0, normals=True, feat=0):
    props = [("float", c) for c in "xyz"]
    if normals:
        props += [("float", c) for c in ("nx", "ny", "nz")]
    if feat:
        props += [("float", f"feat_{i}") for i in range(feat)]
    else:
        props += [("float", f"f_dc_{i}") for i in range(3)]
        props += [("float", f"f_rest_{i}") for i in range(rest)]
    props += [("float", "opacity")]
    props += [("float", f"scale_{i}") for i in range(3)]
    props += [("float", f"rot_{i}") for i in range(4)]
    return props


def records(n, nprops, seed):
    vals = [((i * 37 + seed * 11) % 29) / 7.0 - 2.0 for i in range(n * nprops)]
    return struct.pack(f"<{len(vals)}f", *vals)


def ply_files():
    files = {}
    p = std_props()
    sh0 = header(3, p) + records(3, len(p), 1)
    files["sh0_normals.ply"] = sh0
    p = std_props(rest=9, normals=False)
    files["sh1.ply"] = header(1, p) + records(1, len(p), 2)
    p = std_props(rest=45)
    files["sh3.ply"] = header(1, p) + records(1, len(p), 3)
    p = std_props(feat=4, normals=False)
    files["feat4.ply"] = header(2, p) + records(2, len(p), 4)
    p = list(reversed(std_props(normals=False))) + [("uchar", "red"), ("double", "d"), ("int16", "s")]
    data = b"".join(records(1, 14, 5 + v) + b"\x07" + struct.pack("<dh", 1.5, -3) for v in range(2))
    files["shuffled_extra_crlf.ply"] = header(2, p, extra="comment seed", eol="\r\n") + data
    files["empty.ply"] = header(0, std_props())
    files["truncated_data.ply"] = sh0[:-5]
    files["truncated_header.ply"] = sh0[:60]
    files["trailing.ply"] = sh0 + b"\0"
    files["ascii.ply"] = header(1, std_props(), fmt="ascii 1.0") + b"0 " * 17 + b"\n"
    files["face_list.ply"] = header(0, std_props()).replace(
        b"end_header", b"element face 1\nproperty list uchar int vertex_indices\nend_header") + b"\x03" + bytes(12)
    files["double_opacity.ply"] = header(1, [(("double" if n == "opacity" else t), n) for t, n in std_props()]) + bytes(17 * 4 + 4)
    files["absurd_count.ply"] = header(4000000000, std_props()) + records(1, 17, 6)
    files["missing_rot.ply"] = header(1, std_props()[:-1]) + records(1, 16, 7)
    nan = bytearray(sh0)
    nan[-4 * 8:-4 * 7] = struct.pack("<f", float("nan"))
    files["nan.ply"] = bytes(nan)
    return files


def npy(descr, shape, data, major=1, fortran="False"):
    dims = ", ".join(str(d) for d in shape) + ("," if len(shape) == 1 else "")
    d = f"{{'descr': '{descr}', 'fortran_order': {fortran}, 'shape': ({dims}), }}"
    pre = 10 if major == 1 else 12
    d += " " * (-(pre + len(d) + 1) % 64) + "\n"
    size = struct.pack("<H", len(d)) if major == 1 else struct.pack("<I", len(d))
    return b"\x93NUMPY" + bytes([major, 0]) + size + d.encode() + data


def npy_files():
    f6 = struct.pack("<6f", *[0.5 * i - 1 for i in range(6)])
    return {
        "f32_2x3.npy": npy("<f4", (2, 3), f6),
        "u8_4d.npy": npy("|u1", (1, 2, 2, 3), bytes(range(12))),
        "scalar.npy": npy("<f4", (), f6[:4]),
        "vec_v2.npy": npy("<f4", (6,), f6, major=2),
        "empty.npy": npy("<f4", (0, 4), b""),
        "f64.npy": npy("<f8", (3,), bytes(24)),
        "fortran.npy": npy("<f4", (2, 3), f6, fortran="True"),
        "short.npy": npy("<f4", (2, 3), f6[:-1]),
        "huge_shape.npy": npy("<f4", (4294967296, 4294967296, 16), f6),
    }


def png(w, h, ctype, depth, rows, plte=None):
    def chunk(t, d):
        return struct.pack(">I", len(d)) + t + d + struct.pack(">I", zlib.crc32(t + d))
    ihdr = struct.pack(">IIBBBBB", w, h, depth, ctype, 0, 0, 0)
    raw = b"".join(b"\0" + r for r in rows)
    out = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr)
    if plte:
        out += chunk(b"PLTE", plte)
    return out + chunk(b"IDAT", zlib.compress(raw, 9)) + chunk(b"IEND", b"")


def jpeg(w, h, ncomp):
    """A baseline JPEG, flat grey: every block has DC difference 0 (code
    '0') and then EOB (code '0'), from one-symbol Huffman tables."""
    seg = lambda m, d: b"\xff" + bytes([m]) + struct.pack(">H", len(d) + 2) + d
    dqt = seg(0xDB, b"\x00" + bytes([1] * 64))
    comps = b"".join(bytes([i + 1, 0x11, 0]) for i in range(ncomp))
    sof = seg(0xC0, struct.pack(">BHHB", 8, h, w, ncomp) + comps)
    one = bytes([1] + [0] * 15) + b"\x00"
    dht = seg(0xC4, b"\x00" + one + b"\x10" + one)
    sos = seg(0xDA, bytes([ncomp]) + b"".join(bytes([i + 1, 0]) for i in range(ncomp)) + b"\x00\x3f\x00")
    nbits = 2 * ncomp * ((w + 7) // 8) * ((h + 7) // 8)
    scan = bytes([0] * (nbits // 8)) + (bytes([0xFF >> (nbits % 8)]) if nbits % 8 else b"")
    scan = scan.replace(b"\xff", b"\xff\x00")
    return b"\xff\xd8" + dqt + sof + dht + sos + scan + b"\xff\xd9"


def exif(order, orientation, tag_type=3):
    """An APP1 body: "Exif\\0\\0", a TIFF header, IFD0 with one Orientation entry."""
    e = "<" if order == "II" else ">"
    ifd = struct.pack(e + "H", 1) + struct.pack(e + "HHI", 0x0112, tag_type, 1)
    ifd += struct.pack(e + "HH", orientation, 0) + struct.pack(e + "I", 0)
    return b"Exif\0\0" + order.encode() + struct.pack(e + "HI", 42, 8) + ifd


def app1(body):
    return b"\xff\xe1" + struct.pack(">H", len(body) + 2) + body


def jpeg_with(j, segment):
    """j with segment inserted after SOI."""
    return j[:2] + segment + j[2:]


def exif_files():
    files = {"o%d_%s.bin" % (o, order): exif(order, o) for o in (1, 3, 6, 8) for order in ("II", "MM")}
    files["o5_long.bin"] = exif("II", 5, tag_type=4)
    files["o9.bin"] = exif("MM", 9)
    files["cut.bin"] = exif("II", 6)[:-6]
    files["xmp.bin"] = b"http://ns.adobe.com/xap/1.0/\0<x:xmpmeta/>"
    return files


def image_files():
    rgb = [bytes(v for x in range(5) for v in (x * 40, y * 60, 128)) for y in range(4)]
    files = {
        "rgb_5x4.png": png(5, 4, 2, 8, rgb),
        "grey_3x2.png": png(3, 2, 0, 8, [b"\x00\x80\xff", b"\x10\x20\x30"]),
        "palette_2x1.png": png(2, 1, 3, 8, [b"\x01\x00"], plte=b"\x09\x08\x07\x64\x96\xc8"),
        "rgba16_1x1.png": png(1, 1, 6, 16, [bytes(range(8))]),
        "grey_8x8.jpg": jpeg(8, 8, 1),
        "colour_20x9.jpg": jpeg(20, 9, 3),
    }
    # EXIF orientation 6 (both byte orders), CMYK and YCCK (Adobe APP14
    # transform 0 and 2) after SOI.
    for order in ("II", "MM"):
        files["exif6_%s_20x9.jpg" % order] = jpeg_with(jpeg(20, 9, 3), app1(exif(order, 6)))
    for name, transform in (("cmyk", 0), ("ycck", 2)):
        adobe = b"\xff\xee" + struct.pack(">H", 14) + b"Adobe" + struct.pack(">HHHB", 100, 0, 0, transform)
        files["%s_8x8.jpg" % name] = jpeg_with(jpeg(8, 8, 4), adobe)
    files["truncated.png"] = files["rgb_5x4.png"][:-20]
    files["truncated.jpg"] = files["colour_20x9.jpg"][:-3]
    big = bytearray(files["grey_3x2.png"])
    big[16:24] = struct.pack(">II", 100000, 100000)
    files["huge_header.png"] = bytes(big)
    return files


def st(header, data=b"", pad=True):
    """A safetensors image: u64 LE header length, JSON header, byte buffer."""
    h = json.dumps(header, separators=(",", ":")).encode() if isinstance(header, dict) else header
    if pad:
        h += b" " * (-len(h) % 8)
    return struct.pack("<Q", len(h)) + h + data


def st_entry(dtype, shape, begin, end):
    return {"dtype": dtype, "shape": shape, "data_offsets": [begin, end]}


def safetensors_files():
    f6 = struct.pack("<6f", *[0.25 * i - 1 for i in range(6)])
    mixed = st({"__metadata__": {"format": "gazesplat", "version": "1"},
                "i": st_entry("I64", [2], 0, 16), "w": st_entry("F32", [2, 3], 16, 40),
                "s": st_entry("I32", [], 40, 44), "h": st_entry("F16", [2], 44, 48),
                "b": st_entry("U8", [3], 48, 51), "e": st_entry("F32", [0, 4], 51, 51)},
               struct.pack("<2q", -1, 1 << 40) + f6 + struct.pack("<i2H", 7, 0x3C00, 0xC000) + b"abc")
    loose = (b'{ "\\u00e9\\ud83d\\ude00" : {"data_offsets": [3, 11], "shape": [2], "dtype": "F32"},\n'
             b'"a": {"shape": [3], "dtype": "U8", "data_offsets": [0, 3]}, "__metadata__": {"k": "v\\n"}}   ')
    files = {
        "mixed.safetensors": mixed,
        "loose.safetensors": st(loose, b"xyz" + f6[:8], pad=False),
        "empty.safetensors": st({}),
        "scalar.safetensors": st({"s": st_entry("F32", [], 0, 4)}, f6[:4]),
        "truncated.safetensors": mixed[:-5],
        "short.safetensors": mixed[:6],
        "huge_header_len.safetensors": struct.pack("<Q", 1 << 40) + b"{}",
        "hole.safetensors": st({"a": st_entry("U8", [2], 0, 2), "b": st_entry("U8", [2], 4, 6)}, bytes(6)),
        "overlap.safetensors": st({"a": st_entry("U8", [4], 0, 4), "b": st_entry("U8", [4], 2, 6)}, bytes(6)),
        "nan.safetensors": st({"x": st_entry("F32", [2], 0, 8)}, struct.pack("<2f", 1.0, float("nan"))),
        "float_shape.safetensors": st(b'{"x":{"dtype":"U8","shape":[2.0],"data_offsets":[0,2]}}', bytes(2)),
        "dup_key.safetensors": st(b'{"x":{"dtype":"U8","dtype":"U8","shape":[1],"data_offsets":[0,1]}}', bytes(1)),
        "bad_utf8.safetensors": st(b'{"x\xff":{"dtype":"U8","shape":[1],"data_offsets":[0,1]}}', bytes(1)),
        "ndim9.safetensors": st({"x": st_entry("U8", [1] * 9, 0, 1)}, bytes(1)),
        "overflow.safetensors": st({"x": st_entry("F32", [1 << 32, 1 << 32], 0, 4)}, bytes(4)),
    }
    return files


def main(out):
    for target, files in (("ply", ply_files()), ("npy", npy_files()), ("image", image_files()),
                          ("safetensors", safetensors_files()), ("exif", exif_files())):
        os.makedirs(os.path.join(out, target), exist_ok=True)
        for name, data in files.items():
            with open(os.path.join(out, target, name), "wb") as f:
                f.write(data)


if __name__ == "__main__":
    main(sys.argv[1])
