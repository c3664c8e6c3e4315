#!/usr/bin/python3
"""bench/eval/fit_codes.py on made-up fit caches with known codes.

Two inputs, codes of 4 identity, 6 expression and 12 light values. The
truth run holds expression (0.5, 0.5, 0, 0.2, 0, 0) and lights all 0.1
for both. The run under test has, for input 0, expression (1.5, 0.5, -2,
0.7, 0, 0.5) (mouth_open and brow_raise outside the range; squint's 0.7
and blink's 0 on an end) and lights 0.6 and -0.4 in turn; for input 1, the truth
itself (blink's 0 on an end). So: 2 of 12 slots outside, 3 on an end,
errors mouth_open 0.5, brow_raise 1.0, squint 0.25, pupil 0.25, the
others 0, lights L1 3.00. A file that is not a fit cache, a run with no
input in common and a lone argument are refused. The run under test is
written as eval writes caches now (keyed, "GSFITC2\n" first), the truth
as caches were written before (the fit time first): both are read."""
import os
import re
import struct
import subprocess
import sys
import tempfile

script = sys.argv[1]
MAGIC = 0x42555347


def write_fit(d, n, code, keyed=True):
    os.makedirs(os.path.join(d, "fits"), exist_ok=True)
    head = b"GSFITC2\n" + struct.pack("<Q", 0x1234ABCD) if keyed else b""
    b = head + struct.pack("<d", 6.5) + struct.pack("<III", MAGIC, 1, len(code))
    b += struct.pack(f"<{len(code)}f", *code) + bytes(200)
    with open(os.path.join(d, "fits", f"{n:05d}.bin"), "wb") as f:
        f.write(b)


def run(*args):
    return subprocess.run([sys.executable, script, *args],
                          capture_output=True, text=True)


def fail(msg, out=""):
    print(out)
    sys.exit(f"check_fit_codes: {msg}")


ident = [0.3, -0.2, 0.1, 0.0]
texpr = [0.5, 0.5, 0.0, 0.2, 0.0, 0.0]
with tempfile.TemporaryDirectory() as tmp:
    truth, test = os.path.join(tmp, "truth"), os.path.join(tmp, "test")
    for n in range(2):
        write_fit(truth, n, ident + texpr + [0.1] * 12, keyed=False)
    write_fit(test, 0, ident + [1.5, 0.5, -2.0, 0.7, 0.0, 0.5] + [0.6, -0.4] * 6)
    write_fit(test, 1, ident + texpr + [0.1] * 12)
    r = run(truth, test)
    if r.returncode != 0:
        fail(f"exit {r.returncode}: {r.stderr}", r.stdout)
    rows = [l for l in r.stdout.splitlines() if l.startswith(f"| `{test}`")]
    if len(rows) != 1:
        fail("no row for the run", r.stdout)
    cells = [c.strip() for c in rows[0].strip("|").split("|")]
    want = ["2", "2 of 12", "3", "0.500", "0.000", "1.000", "0.250", "0.000",
            "0.250", "3.00"]
    if cells[1:] != want:
        fail(f"row {cells[1:]}, want {want}", r.stdout)
    # the fits/ folder itself works as well
    r2 = run(os.path.join(truth, "fits"), os.path.join(test, "fits"))
    if r2.returncode != 0 or "| 2 of 12 | 3 |" not in r2.stdout:
        fail("fits/ folders not read the same", r2.stdout + r2.stderr)
    # refusals: a file that is not a fit cache, no input in common
    bad = os.path.join(tmp, "bad")
    os.makedirs(os.path.join(bad, "fits"))
    with open(os.path.join(bad, "fits", "00000.bin"), "wb") as f:
        f.write(bytes(64))
    r = run(truth, bad)
    if r.returncode == 0 or "not a fit cache" not in r.stderr:
        fail("a file of zeros was accepted", r.stdout + r.stderr)
    other = os.path.join(tmp, "other")
    write_fit(other, 7, ident + texpr + [0.1] * 12)
    r = run(truth, other)
    if r.returncode == 0 or "no input in common" not in r.stderr:
        fail("a run with no input in common was accepted", r.stdout + r.stderr)
    r = run(truth)
    if r.returncode == 0 or not re.search("usage", r.stderr):
        fail("one argument was accepted", r.stdout + r.stderr)
print("check_fit_codes: ok")
