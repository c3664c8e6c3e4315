"""A tiny real model and a few normalized synthetic faces, made at test
time with the gazesplat CLI (seconds), cached in the build tree."""
import os
import subprocess


def tiny_model(cli, workdir, seed=1, steps=10):
    path = os.path.join(workdir, "tiny_seed%d.safetensors" % seed)
    if not os.path.exists(path):
        subprocess.run([cli, "train", "--out", path, "--preset", "tiny", "--steps", str(steps),
                        "--seed", str(seed), "--threads", "2", "--log-every", "1000"],
                       check=True, capture_output=True)
    return path


def faces(cli, workdir, size=128, count=3):
    out = os.path.join(workdir, "faces%d" % size)
    if not os.path.exists(os.path.join(out, "labels.jsonl")):
        subprocess.run([cli, "synth", "--out", out, "--count", str(count), "--size", str(size),
                        "--seed-split", "test", "--identities", str(count), "--no-masks"],
                       check=True, capture_output=True)
    names = sorted(os.listdir(os.path.join(out, "images")))
    return [open(os.path.join(out, "images", n), "rb").read() for n in names]
