"""REDIRECT throughput and latency of gazesplatd for cached subjects:
N clients, each sending one-target REDIRECT requests back to back for a
fixed time, cycling over the fitted subjects; reports requests/s (=
images/s), p50/p99 latency, the daemon's CPU time per image and its
renders by path (STATS renders_incremental / renders_full) per client
count. Starts its own daemons on a model (default: an untrained "cpu"
preset model, 256 px; speed does not depend on training).

usage: bench_redirect.py [--build DIR] [--model FILE] [--clients 1,8,32]
                         [--seconds S] [--format raw|png|jpeg]
                         [--workers N] [--threads N] [--subjects N]
                         [--fit-iters N] [--compare] [--transfer]
       bench_redirect.py --overhead    (round trips of HEALTH, answered by
                         the loop, and of a 0 ms SLEEP, which goes through
                         the queue and a worker: the daemon's own cost)

--transfer measures, on the same daemon and in turn with the plain
REDIRECTs, the same requests with detail transfer (the subjects fitted
with keep_image), and prints the plain/transfer ratios.

--compare runs a second daemon with sweep_subjects = 1 beside the first
(each worker keeps one subject's render: with the clients cycling over the
subjects, every request renders in full), the two measured in turn at each
client count, and prints the ratios: the machine's load hits both alike.
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


def run_clients(gc, addr, keys, n, seconds, fmt, transfer):
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
                                          fmt=fmt, transfer=transfer))
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


def cpu_seconds(pid):
    """User + system CPU time of a process (all its threads), seconds."""
    with open("/proc/%d/stat" % pid) as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def measure(gc, d, keys, n, a, transfer=False):
    """One point: clients, images/s, p50, p99, CPU ms/image, renders."""
    addr = "unix:" + d.sock
    with gc.Client(addr) as c:
        st0 = c.stats()
    cpu0 = cpu_seconds(d.proc.pid)
    lat, wall, errors = run_clients(gc, addr, keys, n, a.seconds, a.format, transfer)
    cpu = cpu_seconds(d.proc.pid) - cpu0
    with gc.Client(addr) as c:
        st1 = c.stats()
    if errors:
        print("errors:", errors[:3])
    inc = st1.get("renders_incremental", 0) - st0.get("renders_incremental", 0)
    full = st1.get("renders_full", 0) - st0.get("renders_full", 0)
    return (len(lat) / wall, 1000 * percentile(lat, 50), 1000 * percentile(lat, 99),
            1000 * cpu / max(1, len(lat)), inc, full)


def start_daemon(gc, Daemon, a, model, sweep):
    d = Daemon(os.path.join(a.build, "daemon", "gazesplatd"),
               ["--model", model, "--set", "queue_depth=64", "--set", "workers=%d" % a.workers,
                "--set", "threads=%d" % a.threads, "--set", "sweep_subjects=%d" % sweep]).start()
    addr = "unix:" + d.sock
    while True:
        with gc.Client(addr) as c:
            h = c.health()
        if h.state != gc.pb.Health.LOADING:
            return d, h


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
    ap.add_argument("--threads", type=int, default=0)
    ap.add_argument("--subjects", type=int, default=2)
    ap.add_argument("--compare", action="store_true")
    ap.add_argument("--fit-iters", type=int, default=4)  # distinct subjects need a few
    ap.add_argument("--overhead", action="store_true")
    ap.add_argument("--transfer", action="store_true")
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
    runs = [("kept", 8)] + ([("sweep_subjects=1", 1)] if a.compare else [])
    daemons = []
    try:
        keys = None
        for name, sweep in runs:
            d, h = start_daemon(gc, Daemon, a, model, sweep)
            daemons.append((name, d))
            size = h.image_size
            imgs = faces(cli, work, size, a.subjects)
            with gc.Client("unix:" + d.sock) as c:
                # the same images and labels: the same subject keys in both
                keys = [c.fit(img, max_iters=a.fit_iters, keep_image=a.transfer).subject_key
                        for img in imgs]
                list(c.redirect([(0, 0)], subject=keys[0], fmt=a.format))  # warm-up
        print("model %s, %d px, %d worker(s) x %s thread(s), %s output, %d subjects, %d CPUs, %.0f s per point"
              % (os.path.basename(model), size, a.workers, a.threads or "auto", a.format, len(keys),
                 os.cpu_count(), a.seconds))
        print("%-18s %7s %9s %8s %8s %12s %6s %6s" % ("daemon", "clients", "images/s", "p50 ms", "p99 ms",
                                                 "CPU ms/img", "inc", "full"))
        points = [(name, d, False) for name, d in daemons]
        if a.transfer:
            points.insert(1, ("kept, transfer", daemons[0][1], True))
        for n in (int(x) for x in a.clients.split(",")):
            res = []
            for name, d, transfer in points:
                r = measure(gc, d, keys, n, a, transfer)
                res.append(r)
                print("%-18s %7d %9.1f %8.1f %8.1f %12.1f %6d %6d" % ((name, n) + r))
            for i in range(1, len(res)):
                print("%-18s %7d %8.2fx %7.2fx %7.2fx %11.2fx" % ("ratio 1/%d" % (i + 1), n,
                      res[0][0] / res[i][0], res[i][1] / res[0][1], res[i][2] / res[0][2],
                      res[i][3] / res[0][3]))
            sys.stdout.flush()
    finally:
        for _, d in daemons:
            d.stop()
    return 0


if __name__ == "__main__":
    sys.exit(main())
