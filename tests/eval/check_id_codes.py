#!/usr/bin/python3
"""bench/eval/id_codes.py on a made-up model file and fit caches.

The model holds three learned identity codes of 2 values, (3, 0),
(-3, 0) and (0, 4), and a mean code starting (0, 0). A run on training
pairs has input 0 of identity 0 fitted at (2, 0) (1 from its own code,
nearest it) and input 1 of identity 1 fitted at (1, 0) (4 from its own
code, with two learned codes nearer: (3, 0) at 2 and (0, 4) at 4.12 is
not, so one); a held-out run has one fit and no own-code columns. A
model without codes.train, a file that is not a fit cache and a lone
argument are refused."""
import json
import os
import struct
import subprocess
import sys
import tempfile

script = sys.argv[1]
MAGIC = 0x42555347


def write_model(path, tensors):
    head, blob = {"__metadata__": {"format": "gazesplat-model"}}, b""
    for name, (shape, vals) in tensors.items():
        raw = struct.pack(f"<{len(vals)}f", *vals)
        head[name] = {"dtype": "F32", "shape": shape,
                      "data_offsets": [len(blob), len(blob) + len(raw)]}
        blob += raw
    h = json.dumps(head).encode()
    with open(path, "wb") as f:
        f.write(struct.pack("<Q", len(h)) + h + blob)


def write_fit(d, n, code):
    os.makedirs(os.path.join(d, "fits"), exist_ok=True)
    b = b"GSFITC2\n" + struct.pack("<Q", 7) + struct.pack("<d", 5.0)
    b += struct.pack("<III", MAGIC, 1, len(code)) + struct.pack(f"<{len(code)}f", *code)
    with open(os.path.join(d, "fits", f"{n:05d}.bin"), "wb") as f:
        f.write(b + bytes(100))


def write_run(d, split_train, inputs):
    os.makedirs(d, exist_ok=True)
    with open(os.path.join(d, "summary.md"), "w") as f:
        f.write("# gazesplat eval\n\n")
        if split_train:
            f.write("- **training identities** (`--split train`): faces ...\n")
    with open(os.path.join(d, "pairs.csv"), "w") as f:
        f.write("method,pair,input,identity\n")
        for i, (ident, _) in enumerate(inputs):
            f.write(f"model,{i},{i},{ident}\n")
    for i, (_, code) in enumerate(inputs):
        write_fit(d, i, code + [0.0] * 18)


def run(*args):
    return subprocess.run([sys.executable, script, *args], capture_output=True, text=True)


def fail(msg, out=""):
    print(out)
    sys.exit(f"check_id_codes: {msg}")


with tempfile.TemporaryDirectory() as tmp:
    model = os.path.join(tmp, "m.safetensors")
    write_model(model, {"codes.train": ([3, 2], [3, 0, -3, 0, 0, 4]),
                        "codes.mean": ([20], [0.0] * 20)})
    tr, ho = os.path.join(tmp, "train"), os.path.join(tmp, "held")
    write_run(tr, True, [(0, [2.0, 0.0]), (1, [1.0, 0.0])])
    write_run(ho, False, [(0, [2.0, 0.0])])
    r = run(model, tr, ho)
    if r.returncode != 0:
        fail(f"exit {r.returncode}: {r.stderr}", r.stdout)
    rows = {}  # the first table: one row per run (the details follow)
    for l in r.stdout.splitlines():
        if l.startswith("| `"):
            rows.setdefault(l.split("|")[1].strip(),
                            [c.strip() for c in l.strip().strip("|").split("|")])
    t = rows.get(f"`{tr}`")
    # 2 fits, from the mean 1.5, own-code distance mean 2.5, nearest own 1 of 2
    if not t or t[1] != "2" or t[2] != "1.50" or t[4] != "2.50" or t[6] != "1 of 2":
        fail(f"training row {t}", r.stdout)
    h = rows.get(f"`{ho}`")
    if not h or h[1] != "1" or h[4:] != ["–", "–", "–"]:
        fail(f"held-out row {h}", r.stdout)
    det = [l for l in r.stdout.splitlines() if l.startswith(f"| `{tr}` | 1 |")]
    if len(det) != 1 or [c.strip() for c in det[0].strip("|").split("|")][2:] != ["1", "4.00", "1", "3.00"]:
        fail(f"detail row {det}", r.stdout)
    if "3 learned identity codes of 2" not in r.stdout:
        fail("model line", r.stdout)
    # refusals
    bad = os.path.join(tmp, "bad.safetensors")
    write_model(bad, {"codes.mean": ([20], [0.0] * 20)})
    r = run(bad, tr)
    if r.returncode == 0 or "no codes.train" not in r.stderr:
        fail("a model without codes.train was accepted", r.stdout + r.stderr)
    junk = os.path.join(tmp, "junk")
    os.makedirs(os.path.join(junk, "fits"))
    with open(os.path.join(junk, "fits", "00000.bin"), "wb") as f:
        f.write(bytes(64))
    r = run(model, junk)
    if r.returncode == 0 or "not a fit cache" not in r.stderr:
        fail("a file of zeros was accepted", r.stdout + r.stderr)
    r = run(model)
    if r.returncode == 0 or "usage" not in r.stderr:
        fail("one argument was accepted", r.stdout + r.stderr)
print("check_id_codes: ok")
