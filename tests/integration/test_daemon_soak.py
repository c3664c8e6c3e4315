"""gazesplatd under load with a tiny real model (label slow):
  * 32 clients x 50 requests (HEALTH, STATS and REDIRECT of cached
    subjects) with no lost or mixed-up replies;
  * resident memory grows < 10% after warm-up;
  * kill -9 during a FIT, restart: the persisted subjects are intact.
usage: test_daemon_soak.py GAZESPLATD GAZESPLAT_CLI WORKDIR"""
import os
import signal
import sys
import threading
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.join(HERE, "..", "..", "clients", "python"))
from daemon_util import Checks, Daemon  # noqa: E402
from model_fixture import faces, tiny_model  # noqa: E402
import gazesplat_client as gc  # noqa: E402

CLIENTS, REQUESTS = 32, 50


def rss_kb(pid):
    with open("/proc/%d/status" % pid) as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    return 0


def wait_ready(addr):
    for _ in range(600):
        with gc.Client(addr) as c:
            if c.health().state == gc.pb.Health.READY:
                return True
        time.sleep(0.05)
    return False


def client_run(addr, keys, n, errors, idx):
    try:
        with gc.Client(addr, retry_busy=1000) as c:
            for i in range(n):
                if i % 10 == 0:
                    key = keys[(idx + i) % len(keys)]
                    res = list(c.redirect([(idx % 20, i % 30)], subject=key, fmt="raw"))
                    if len(res) != 1 or res[0].index != 0 or res[0].target.gaze.pitch_deg != idx % 20:
                        errors.append("client %d request %d: bad images %s" % (idx, i, res))
                elif i % 2:
                    c.health()
                else:
                    c.stats()
    except Exception as e:  # any mismatch raises in the client
        errors.append("client %d: %r" % (idx, e))


def load(t, addr, keys):
    errors = []
    threads = [threading.Thread(target=client_run, args=(addr, keys, REQUESTS, errors, i))
               for i in range(CLIENTS)]
    for th in threads:
        th.start()
    for th in threads:
        th.join(300)
    t.check(not errors, "%d client errors, first: %s" % (len(errors), errors[:3]))


def main():
    daemon, cli, work = (os.path.abspath(a) for a in sys.argv[1:4])
    os.makedirs(work, exist_ok=True)
    t = Checks()
    model = tiny_model(cli, work, seed=1)
    imgs = faces(cli, work, 128, 3)
    state = os.path.join(work, "state_soak")
    os.makedirs(state, exist_ok=True)
    for f in os.listdir(state):
        os.unlink(os.path.join(state, f))
    # Two workers: the queue gives a REDIRECT to the worker that keeps its
    # subject's render (work.c); no reply may be lost or mixed up by that.
    args = ["--model", model, "--state-dir", state, "--set", "queue_depth=64", "--set", "photo_input=no",
            "--set", "max_connections=128", "--set", "workers=2", "--set", "threads=1"]
    d = Daemon(daemon, args).start()
    try:
        addr = "unix:" + d.sock
        t.check(wait_ready(addr), "model loaded")
        with gc.Client(addr) as c:
            keys = [c.fit(img, max_iters=3).subject_key for img in imgs[:2]]
        load(t, addr, keys)  # warm-up: allocator, caches, thread stacks
        before = rss_kb(d.proc.pid)
        load(t, addr, keys)
        after = rss_kb(d.proc.pid)
        print("RSS after warm-up %d kB, after %d more requests %d kB" % (before, CLIENTS * REQUESTS, after))
        t.check(after < before * 1.10, "RSS grew from %d to %d kB" % (before, after))
        with gc.Client(addr) as c:
            st = c.stats()
            t.check(st["protocol_errors"] == 0 and st["images_out"] >= 2 * CLIENTS * REQUESTS // 10,
                    "stats %s" % st)
            t.check(st["renders_incremental"] > 10 * st["renders_full"],
                    "renders: %d incremental, %d full" % (st["renders_incremental"], st["renders_full"]))
            # kill -9 in the middle of a long FIT.
            c.send(gc.FT.FRAME_FIT, gc.pb.FitRequest(
                image=gc.pb.Image(format=gc.pb.FORMAT_PNG, data=imgs[2]), max_iters=100000), 77,
                b"K" * 16)
            time.sleep(0.5)
            os.kill(d.proc.pid, signal.SIGKILL)
            d.proc.wait()
            d.proc = None
        d = Daemon(daemon, args).start()
        addr = "unix:" + d.sock
        t.check(wait_ready(addr), "model loaded after kill -9")
        with gc.Client(addr) as c:
            for k in keys:
                t.check(len(list(c.redirect([(0, 0)], subject=k))) == 1, "subject %s survived" % k.hex())
            try:
                list(c.redirect([(0, 0)], subject=b"K" * 16))
                t.check(False, "the interrupted fit left a subject")
            except gc.GazesplatError as e:
                t.check(e.code == gc.pb.ERR_UNKNOWN_SUBJECT, "interrupted fit: %s" % e)
    finally:
        rc = d.stop()
        if t.failures:
            print(d.log()[-5000:])
    t.check(rc == 0, "exit %s" % rc)
    return t.status()


if __name__ == "__main__":
    sys.exit(main())
