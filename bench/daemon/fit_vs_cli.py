"""The daemon's FIT against the CLI's fit of the same face, side by side.

Each round runs `gazesplat fit` (a process: model load, fit, fine-tune)
and then a FIT of the same image on a running gazesplatd (a fresh subject
key each time, so nothing comes from the cache), with the same iterations
and fine-tuning steps. It prints both times per round and the ratio
daemon / CLI per round (pairs run back to back, so a change in machine
load hits both alike), then the medians. The CLI's time is its own report
of the fit and the fine-tune (without the model load), so the ratio
compares the same work.

usage: /usr/bin/python3 bench/daemon/fit_vs_cli.py [--model M] [--rounds N]
           [--iters 45] [--finetune 15] [--build build]
"""
import argparse
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.join(HERE, "..", "..")
sys.path.insert(0, os.path.join(ROOT, "clients", "python"))
sys.path.insert(0, os.path.join(ROOT, "tests", "integration"))
from daemon_util import Daemon  # noqa: E402
gc = None  # the client, imported once the build tree is known


def cli_fit_seconds(cli, model, image, iters, steps, out):
    r = subprocess.run([cli, "fit", "--model", model, "--image", image, "--iters", str(iters),
                        "--finetune", str(steps), "--out", out],
                       check=True, capture_output=True, text=True)
    secs = [float(x) for x in re.findall(r" in ([0-9.]+) s", r.stderr + r.stdout)]
    if len(secs) != 2:
        raise RuntimeError("unexpected fit output: %s" % r.stderr)
    return sum(secs)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--model", default=os.path.join(ROOT, "models", "gazegaussian-cpu.safetensors"))
    ap.add_argument("--build", default=os.path.join(ROOT, "build"))
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--iters", type=int, default=45)
    ap.add_argument("--finetune", type=int, default=15)
    a = ap.parse_args()
    global gc
    os.environ.setdefault("GAZESPLAT_PB2_DIR", os.path.join(a.build, "python"))
    import gazesplat_client
    gc = gazesplat_client
    cli = os.path.join(a.build, "clients", "cli", "gazesplat")
    daemon_bin = os.path.join(a.build, "daemon", "gazesplatd")
    work = tempfile.mkdtemp(prefix="fit_vs_cli_")
    model_size = None
    d = Daemon(daemon_bin, ["--model", a.model, "--set", "workers=1"]).start()
    try:
        end = time.time() + 120
        while time.time() < end:
            with gc.Client(d.sock) as c:
                h = c.health()
            if h.state == gc.pb.Health.READY:
                model_size = h.image_size
                break
            time.sleep(0.1)
        if not model_size:
            sys.exit("daemon never became ready:\n" + d.log())
        subprocess.run([cli, "synth", "--out", os.path.join(work, "faces"), "--count", "1", "--size",
                        str(model_size), "--seed-split", "test", "--identities", "1", "--no-masks"],
                       check=True, capture_output=True)
        img_dir = os.path.join(work, "faces", "images")
        image = os.path.join(img_dir, sorted(os.listdir(img_dir))[0])
        data = open(image, "rb").read()
        rows = []
        for k in range(a.rounds):
            t_cli = cli_fit_seconds(cli, a.model, image, a.iters, a.finetune, os.path.join(work, "s.bin"))
            with gc.Client(d.sock, timeout=600) as c:
                t0 = time.time()
                c.fit(data, key=os.urandom(16), max_iters=a.iters, finetune_steps=a.finetune)
                t_daemon = time.time() - t0
            rows.append((t_cli, t_daemon, t_daemon / t_cli))
            print("round %d: CLI %.2f s, daemon %.2f s, daemon/CLI %.3f" % ((k + 1,) + rows[-1]),
                  flush=True)
        with gc.Client(d.sock) as c:
            st = c.stats()
        print("daemon: %d pool threads, OpenBLAS %d thread(s)" % (st["pool_threads"], st["blas_threads"]))
        med = [statistics.median(r[i] for r in rows) for i in range(3)]
        print("median: CLI %.2f s, daemon %.2f s, daemon/CLI %.3f (min %.3f, max %.3f)"
              % (med[0], med[1], med[2], min(r[2] for r in rows), max(r[2] for r in rows)))
    finally:
        d.stop()


if __name__ == "__main__":
    main()
