#!/usr/bin/python3
"""The source tree's structure, read from the C sources themselves:

- import circles: inside each checked folder (lib/model, daemon by
  default), files that include or call each other in a loop. A file A
  has an arrow to B when it includes B's header (a quoted include naming
  B's base name with .h) or calls a function that B alone defines
  (non-static definitions). Circles are the strongly connected
  components of more than one file (Tarjan's algorithm).
- long functions: every function over 120 lines in lib/ and daemon/ must
  be named in LONG_OK with the reason it stays long (a hot kernel).
- the serving path and training: no file of SERVING calls a function that
  the training module (lib/train) or the synthetic generator (lib/synth:
  it makes training data) defines, so gazesplatd and the live engine link
  neither.

usage: test_structure.py ROOT          check the tree, exit 1 on a finding
       test_structure.py --self-test   the checker finds a made-up circle
                                       and a made-up long function
       test_structure.py ROOT --list   print the arrows and the lengths
"""
import glob
import os
import re
import sys
import tempfile

CHECKED = ["lib/model", "daemon"]
TRAINING = ["lib/train", "lib/synth"]
SERVING = ["lib/model", "lib/redirect", "lib/face", "lib/capture", "daemon"]
LIMIT = 120
# Hot kernels that stay whole: splitting them would cost a call per
# Gaussian or per pixel, or break the one pass the code is built around.
LONG_OK = {
    "lib/model/frame.c:gs_frame_backward": "the paired backward of one forward: the streams, "
    "rasterizer and renderer in the order the forward ran, sharing its saved state",
    "lib/raster/raster.c:project_backward_one": "one Gaussian's projection backward, per Gaussian "
    "in the inner loop (the Jacobian chain written out)",
    "lib/raster/raster_tiles.c:tile_forward_nv": "the tile compositing loop, per pixel and Gaussian",
    "lib/synth/head.c:head_sdf_impl": "the head's signed distance, evaluated per ray-march step",
}

DEF_RE = re.compile(r"^(?!static\b)[A-Za-z_][\w \*]*?\b([a-z]\w*)\s*\([^;{]*\)\s*\{", re.M)
INC_RE = re.compile(r'^#include\s+"([^"]+)"', re.M)
COMMENT_RE = re.compile(r"/\*.*?\*/|//[^\n]*", re.S)


def strip_comments(text):
    return COMMENT_RE.sub("", text)


def arrows(folder):
    """{(a, b): names} for the .c files of folder: a includes b's header or
    calls a function b alone defines."""
    files = sorted(glob.glob(os.path.join(folder, "*.c")))
    base = {os.path.splitext(os.path.basename(f))[0]: f for f in files}
    defs = {}
    for f in files:
        for m in DEF_RE.finditer(strip_comments(open(f).read())):
            defs.setdefault(m.group(1), set()).add(f)
    out = {}
    for f in files:
        src = strip_comments(open(f).read())
        for inc in INC_RE.findall(src):
            stem = os.path.splitext(os.path.basename(inc))[0]
            b = base.get(stem)
            if b and b != f and inc.endswith(".h") and "/" not in inc:
                out.setdefault((f, b), set()).add("#include " + inc)
        for name, where in defs.items():
            if len(where) == 1 and f not in where and re.search(r"\b" + name + r"\s*\(", src):
                out.setdefault((f, next(iter(where))), set()).add(name)
    return out


def circles(edges):
    g = {}
    for a, b in edges:
        g.setdefault(a, set()).add(b)
        g.setdefault(b, set())
    index, low, stack, on, found, counter = {}, {}, [], set(), [], [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in sorted(g[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                found.append(sorted(comp))

    for v in sorted(g):
        if v not in index:
            visit(v)
    return found


def long_functions(root, folders=("lib", "daemon")):
    """[(lines, 'path:name')] of every function over LIMIT lines: from the
    line its signature starts on to its closing brace in column 0."""
    out = []
    for folder in folders:
        for f in sorted(glob.glob(os.path.join(root, folder, "**", "*.c"), recursive=True)):
            lines = open(f).read().split("\n")
            i = 0
            while i < len(lines):
                if lines[i].startswith("{"):
                    s = i - 1
                    while s > 0 and not re.match(r"[A-Za-z_]", lines[s]):
                        s -= 1
                    m = re.search(r"(\w+)\s*\(", lines[s])
                    k = i + 1
                    while k < len(lines) and not lines[k].startswith("}"):
                        k += 1
                    if m and k - s + 1 > LIMIT:
                        out.append((k - s + 1, os.path.relpath(f, root) + ":" + m.group(1)))
                    i = k
                i += 1
    return out


def training_calls(root):
    """[(file, names)] of SERVING's files that call functions TRAINING's
    folders define."""
    defs = set()
    for folder in TRAINING:
        for f in sorted(glob.glob(os.path.join(root, folder, "*.c"))):
            defs.update(m.group(1) for m in DEF_RE.finditer(strip_comments(open(f).read())))
    out = []
    for folder in SERVING:
        for f in sorted(glob.glob(os.path.join(root, folder, "*.c"))):
            src = strip_comments(open(f).read())
            names = sorted(n for n in defs if re.search(r"\b" + n + r"\s*\(", src))
            if names:
                out.append((os.path.relpath(f, root), names))
    return out


def check(root, verbose=False):
    bad = 0
    for f, names in training_calls(root):
        bad += 1
        print("%s calls training code (%s): %s" % (f, " or ".join(TRAINING), ", ".join(names)))
    for folder in CHECKED:
        e = arrows(os.path.join(root, folder))
        if verbose:
            for (a, b), names in sorted(e.items()):
                print("%s -> %s: %s" % (os.path.relpath(a, root), os.path.relpath(b, root),
                                        ", ".join(sorted(names))))
        for comp in circles(e):
            bad += 1
            print("circle in %s: %s" % (folder, " <-> ".join(os.path.relpath(c, root) for c in comp)))
            for (a, b), names in sorted(e.items()):
                if a in comp and b in comp:
                    print("  %s -> %s: %s" % (os.path.basename(a), os.path.basename(b),
                                              ", ".join(sorted(names))))
    for n, where in long_functions(root):
        if verbose:
            print("%d lines: %s%s" % (n, where, " (kept: %s)" % LONG_OK[where] if where in LONG_OK else ""))
        if where not in LONG_OK:
            bad += 1
            print("%s is %d lines (over %d): split it, or name it in LONG_OK with why" % (where, n, LIMIT))
    return bad


def self_test():
    with tempfile.TemporaryDirectory() as t:
        d = os.path.join(t, "lib", "model")
        os.makedirs(d)
        os.makedirs(os.path.join(t, "daemon"))
        open(os.path.join(d, "a.c"), "w").write('#include "b.h"\nint gs_a(void)\n{\n    return gs_b();\n}\n')
        open(os.path.join(d, "b.c"), "w").write("int gs_b(void)\n{\n    return 1;\n}\n"
                                                "int gs_c(void)\n{\n    return gs_a();\n}\n")
        open(os.path.join(d, "c.c"), "w").write("/* gs_a( in a comment is no call */\nint gs_d(void)\n"
                                                "{\n    return gs_b();\n}\n")
        body = "".join("    x += %d;\n" % i for i in range(130))
        open(os.path.join(t, "daemon", "long.c"), "w").write("int gsd_long(int x)\n{\n%s    return x;\n}\n"
                                                             % body)
        os.makedirs(os.path.join(t, "lib", "train"))
        open(os.path.join(t, "lib", "train", "train.c"), "w").write("int gs_train_x(void)\n{\n    return 0;\n}\n")
        open(os.path.join(t, "daemon", "serve.c"), "w").write("int gsd_serve(void)\n{\n    return gs_train_x();\n}\n")
        os.makedirs(os.path.join(t, "lib", "synth"))
        open(os.path.join(t, "lib", "synth", "gen.c"), "w").write("int gs_synth_y(void)\n{\n    return 0;\n}\n")
        open(os.path.join(t, "daemon", "serve2.c"), "w").write("int gsd_serve2(void)\n{\n    return gs_synth_y();\n}\n")
        e = arrows(d)
        ok = training_calls(t) == [("daemon/serve.c", ["gs_train_x"]), ("daemon/serve2.c", ["gs_synth_y"])]
        ok = ok and circles(e) == [[os.path.join(d, "a.c"), os.path.join(d, "b.c")]]
        ok = ok and (os.path.join(d, "c.c"), os.path.join(d, "a.c")) not in e
        lf = long_functions(t)
        ok = ok and [w for _, w in lf] == ["daemon/long.c:gsd_long"]
        ok = ok and check(t) == 4
        print("self-test:", "ok" if ok else "FAILED")
        return 0 if ok else 1


def main():
    if sys.argv[1:] == ["--self-test"]:
        return self_test()
    if len(sys.argv) < 2:
        print(__doc__)
        return 2
    bad = check(sys.argv[1], verbose="--list" in sys.argv)
    print("structure: %s" % ("ok" if not bad else "%d finding(s)" % bad))
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
