"""gazesplatd's resident memory by fine-tuned subject.

Starts one daemon (one worker) on the model, then fits N synthetic faces
in turn, each fine-tuned and rendered once by key, and prints the daemon's
VmRSS (and its peak so far, VmHWM: a fit's and a fine-tune's working set
while they run) and its STATS tuned/subject bytes after each. The first
subjects pay the fixed costs (the worker's context, its tuned slots: a
model clone and a context each, `tuned_subjects`); later ones show the
margin per subject (daemon/README.md, "Memory").

usage: /usr/bin/python3 bench/daemon/rss_per_subject.py [--model M] [--build build]
           [--subjects 5] [--tuned-subjects 2] [--iters 10] [--finetune 3]
"""
import argparse
import os
import re
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.join(HERE, "..", "..")
sys.path.insert(0, os.path.join(ROOT, "clients", "python"))
sys.path.insert(0, os.path.join(ROOT, "tests", "integration"))
from daemon_util import Daemon  # noqa: E402


def rss_mb(pid, field="VmRSS"):
    with open("/proc/%d/status" % pid) as f:
        return int(re.search(field + r":\s+(\d+)", f.read()).group(1)) / 1024.0


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--model", default=os.path.join(ROOT, "models", "gazegaussian-cpu.safetensors"))
    ap.add_argument("--build", default=os.path.join(ROOT, "build"))
    ap.add_argument("--subjects", type=int, default=5)
    ap.add_argument("--tuned-subjects", type=int, default=2)
    ap.add_argument("--iters", type=int, default=10)
    ap.add_argument("--finetune", type=int, default=3)
    a = ap.parse_args()
    os.environ.setdefault("GAZESPLAT_PB2_DIR", os.path.join(a.build, "python"))
    import gazesplat_client as gc
    work = tempfile.mkdtemp(prefix="rss_subject_")
    d = Daemon(os.path.join(a.build, "daemon", "gazesplatd"),
               ["--model", a.model, "--set", "workers=1",
                "--set", "tuned_subjects=%d" % a.tuned_subjects]).start()
    try:
        end = time.time() + 120
        size = 0
        while time.time() < end and not size:
            with gc.Client(d.sock) as c:
                h = c.health()
            size = h.image_size if h.state == gc.pb.Health.READY else 0
            time.sleep(0.2)
        if not size:
            sys.exit("daemon never became ready:\n" + d.log())
        faces = os.path.join(work, "faces")
        subprocess.run([os.path.join(a.build, "clients", "cli", "gazesplat"), "synth", "--out", faces,
                        "--count", str(a.subjects), "--size", str(size), "--seed-split", "test",
                        "--identities", str(a.subjects), "--no-masks"], check=True, capture_output=True)
        names = sorted(os.listdir(os.path.join(faces, "images")))
        print("tuned_subjects %d, idle: RSS %.0f MB" % (a.tuned_subjects, rss_mb(d.proc.pid)), flush=True)
        for i, n in enumerate(names):
            img = open(os.path.join(faces, "images", n), "rb").read()
            with gc.Client(d.sock, timeout=600) as c:
                key = c.fit(img, max_iters=a.iters, finetune_steps=a.finetune).subject_key
                list(c.redirect([(0, 0)], subject=key))
                st = c.stats()
            print("subjects %d: RSS %.0f MB (peak %.0f MB), tuned blocks %.1f MB, subject cache %.1f KB"
                  % (i + 1, rss_mb(d.proc.pid), rss_mb(d.proc.pid, "VmHWM"), st["tuned_bytes"] / 2**20,
                     st["cache_bytes"] / 1024), flush=True)
    finally:
        d.stop()


if __name__ == "__main__":
    main()
