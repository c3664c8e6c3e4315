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


def daemon_fixture(argv, state_name, size=128, count=3):
    """What the model-backed daemon tests start from, for argv
    (GAZESPLATD GAZESPLAT_CLI WORKDIR): the binaries, two tiny models
    (seeds 1 and 2), `count` faces and an emptied state directory."""
    daemon, cli, work = (os.path.abspath(a) for a in argv[:3])
    os.makedirs(work, exist_ok=True)
    state = os.path.join(work, state_name)
    os.makedirs(state, exist_ok=True)
    for f in os.listdir(state):
        os.unlink(os.path.join(state, f))
    return {"daemon": daemon, "cli": cli, "work": work, "state": state,
            "model": tiny_model(cli, work, seed=1), "other": tiny_model(cli, work, seed=2),
            "faces": faces(cli, work, size, count)}
