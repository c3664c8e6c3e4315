"""Checks that proto/PROTOCOL.md carries every frame printed by
gs_proto_examples verbatim, that each frame decodes in Python with
struct and (when available) the generated gazesplat.gazesplat_pb2, and that its
appendix reproduces proto/gazesplat.proto byte for byte.
usage: check_examples.py EXAMPLES_TOOL PROTOCOL.md [PYTHON_DIR]
(PYTHON_DIR: the build tree's python/, which holds the package gazesplat)"""
import os
import re
import struct
import subprocess
import sys


def main():
    tool, doc = sys.argv[1], sys.argv[2]
    out = subprocess.run([tool], check=True, capture_output=True, text=True).stdout
    text = open(doc, encoding="utf-8").read()
    blocks = re.findall(r"example (\w+): [^\n]*\n```hex\n(.*?)```", out, re.S)
    if not blocks:
        print("no examples printed", file=sys.stderr)
        return 1
    failures = 0
    named = re.findall(r"^example \w+:", out, re.M)
    if len(named) != len(blocks):
        print(f"{len(named)} examples printed but {len(blocks)} parsed", file=sys.stderr)
        failures += 1
    for name, body in blocks:
        if ("```hex\n" + body + "```") not in text:
            print(f"PROTOCOL.md lacks example '{name}' as printed:\n{body}", file=sys.stderr)
            failures += 1
        data = bytes.fromhex("".join(line[4:] for line in body.splitlines()))
        magic, ver, typ, n, key, rid = struct.unpack("<4sHHI16sI", data[:32])
        if magic != b"GAZE" or ver != 1 or n != len(data) - 32:
            print(f"example '{name}': bad header {data[:32].hex()}", file=sys.stderr)
            failures += 1
    proto = open(os.path.join(os.path.dirname(os.path.abspath(doc)), "gazesplat.proto"), encoding="utf-8").read()
    appendix = re.search(r"## Appendix: gazesplat.proto\n.*?```proto\n(.*?)```", text, re.S)
    if not appendix or appendix.group(1) != proto:
        print("PROTOCOL.md's appendix is not gazesplat.proto verbatim: copy the file into it",
              file=sys.stderr)
        failures += 1
    pb2 = sys.argv[3] if len(sys.argv) > 3 else None
    if pb2 and os.path.exists(os.path.join(pb2, "gazesplat", "gazesplat_pb2.py")):
        sys.path.insert(0, pb2)
        from gazesplat import gazesplat_pb2 as pb
        classes = {1: pb.Hello, 2: pb.HelloOk, 3: pb.HealthRequest, 7: pb.FitRequest,
                   9: pb.RedirectRequest, 11: pb.Done, 12: pb.Cancel, 13: pb.Error, 14: pb.Busy,
                   15: pb.LivePolicyRequest}
        for name, body in blocks:
            data = bytes.fromhex("".join(line[4:] for line in body.splitlines()))
            typ = struct.unpack("<H", data[6:8])[0]
            msg = classes[typ].FromString(data[32:])
            if msg.SerializeToString() != data[32:]:
                print(f"example '{name}': Python re-encodes differently", file=sys.stderr)
                failures += 1
    print(f"{len(blocks)} examples checked, {failures} failures")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
