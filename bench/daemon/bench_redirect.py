"""REDIRECT throughput and latency of gazesplatd for cached subjects:
N clients, each sending one-target REDIRECT requests back to back for a
fixed time; reports requests/s (= images/s) and p50/p99 latency per client
count. Starts its own daemon on a model (default: an untrained "cpu"
preset model, 256 px; speed does not depend on training).

usage: bench_redirect.py [--build DIR] [--model FILE] [--clients 1,8,32]
                         [--seconds S] [--format raw|png]
       bench_redirect.py --overhead    (round trips of HEALTH, answered by
                         the loop, and of a 0 ms SLEEP, which goes through
                         the queue and a worker: the daemon's own cost)
"""
import argparse
import os
import subprocess
import sys
import tempfile
import threading
import time

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..")
sys.path.insert(0, os.path.join(ROOT, "clients", "python"))
sys.path.insert(0, os.path.join(ROOT, "tests", "integration"))


def percentile(xs, p):
    xs = sorted(xs)
    return xs[min(len(xs) - 1, int(p / 100.0 * len(xs)))] if xs else float("nan")


def run_clients(gc, addr, keys, n, seconds, fmt):
    lat, errors = [], []
    lock = threading.Lock()
    stop = time.time() + seconds

    def one(i):
        try:
            with gc.Client(addr, retry_busy=100000) as c:
                k = 0
                while time.time() < stop:
                    t0 = time.perf_counter()
                    out = list(c.redirect([((i + k) % 20 - 10, k % 40 - 20)], subject=keys[(i + k) % len(keys)],
                                          fmt=fmt))
                    dt = time.perf_counter() - t0
                    assert len(out) == 1
                    with lock:
                        lat.append(dt)
                    k += 1
        except Exception as e:
            errors.append(repr(e))

    threads = [threading.Thread(target=one, args=(i,)) for i in range(n)]
    t0 = time.time()
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    return lat, time.time() - t0, errors


def overhead(gc, Daemon, a, n=5000):
    d = Daemon(os.path.join(a.build, "daemon", "gazesplatd"), ["--set", "debug_requests=yes"]).start()
    try:
        with gc.Client("unix:" + d.sock) as c:
            for name, ft, msg, want in [
                    ("HEALTH (loop thread)", gc.FT.FRAME_HEALTH, gc.pb.HealthRequest(), gc.FT.FRAME_HEALTH_OK),
                    ("SLEEP 0 ms (queue + worker)", gc.FT.FRAME_SLEEP, gc.pb.Sleep(ms=0), gc.FT.FRAME_SLEEP_OK)]:
                t0 = time.perf_counter()
                for _ in range(n):
                    c.call(ft, msg, want)
                print("%-28s %6.0f us per round trip (%d, one Python client)"
                      % (name, (time.perf_counter() - t0) / n * 1e6, n))
    finally:
        d.stop()
    return 0


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--build", default=os.path.join(ROOT, "build"))
    ap.add_argument("--model", default=None)
    ap.add_argument("--clients", default="1,8,32")
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--format", default="raw", choices=["raw", "png", "jpeg"])
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--overhead", action="store_true")
    a = ap.parse_args()
    os.environ.setdefault("GAZESPLAT_PB2_DIR", os.path.join(a.build, "python"))
    import gazesplat_client as gc
    from daemon_util import Daemon
    from model_fixture import faces
    if a.overhead:
        return overhead(gc, Daemon, a)
    cli = os.path.join(a.build, "clients", "cli", "gazesplat")
    work = tempfile.mkdtemp(prefix="gsd_bench_")
    model = a.model
    if not model:
        model = os.path.join(work, "cpu.safetensors")
        subprocess.run([cli, "train", "--out", model, "--preset", "cpu", "--steps", "1"],
                       check=True, capture_output=True)
    d = Daemon(os.path.join(a.build, "daemon", "gazesplatd"),
               ["--model", model, "--set", "queue_depth=64", "--set", "workers=%d" % a.workers]).start()
    try:
        addr = "unix:" + d.sock
        while True:
            with gc.Client(addr) as c:
                h = c.health()
            if h.state != gc.pb.Health.LOADING:
                break
            time.sleep(0.05)
        size = h.image_size
        imgs = faces(cli, work, size, 2)
        with gc.Client(addr) as c:
            keys = [c.fit(img, max_iters=1).subject_key for img in imgs]
            list(c.redirect([(0, 0)], subject=keys[0], fmt=a.format))  # warm-up
        print("model %s, %d px, %d worker(s), %s output, %d CPUs, %.0f s per point"
              % (os.path.basename(model), size, a.workers, a.format, os.cpu_count(), a.seconds))
        print("%8s %10s %10s %10s" % ("clients", "images/s", "p50 ms", "p99 ms"))
        for n in (int(x) for x in a.clients.split(",")):
            lat, wall, errors = run_clients(gc, addr, keys, n, a.seconds, a.format)
            if errors:
                print("errors:", errors[:3])
            print("%8d %10.1f %10.1f %10.1f" % (n, len(lat) / wall, 1000 * percentile(lat, 50),
                                                 1000 * percentile(lat, 99)))
    finally:
        d.stop()
    return 0


if __name__ == "__main__":
    sys.exit(main())
