"""Failover through HAProxy (the shipped deploy/haproxy config): three
daemons, one thread per subject sending REDIRECTs through
gazesplat.routing.SubjectClient; one daemon is killed (SIGKILL) under that
load. Checked: every request returns each of its targets exactly once
(no image lost or duplicated), with the bytes the subject gave before the
kill; a request meets at most one retryable error; the dead daemon's
subjects are fitted again once each, on the daemon the ring now picks,
and held there only; the other subjects stay where they were (no fit
anywhere else). Times are printed, never checked (bench/daemon/scale_bench.py
measures them).
usage: test_scale_failover.py GAZESPLATD GAZESPLAT_CLI WORKDIR"""
import hashlib
import os
import shutil
import sys
import threading
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from scale_util import Checks, Haproxy, TcpDaemon, synth_faces, workdir  # noqa: E402
from gazesplat import Client  # noqa: E402
from gazesplat.routing import SubjectClient, subject_key  # noqa: E402

SUBJECTS = 6
ITERS = 3
TARGETS = [(10, 0), (0, 15), (-10, -20)]
BEFORE, AFTER = 2, 3   # requests per subject before the kill, and after it


def held(daemons):
    out = {}
    for d in daemons:
        with Client(d.addr) as c:
            out[d.name] = set(bytes(k) for k in c.health(list_subjects=True).subject_keys)
    return out


def home_of(where, k):
    at = [n for n, s in where.items() if k in s]
    return at[0] if len(at) == 1 else at


class Worker(threading.Thread):
    """The requests of one subject: BEFORE of them, then (once `killed` is
    set) AFTER more; each request's results and errors recorded."""

    def __init__(self, addr, face, key, killed):
        super().__init__(daemon=True)
        self.sc = SubjectClient(addr, face, key=key, max_iters=ITERS)
        self.killed = killed
        self.requests = []  # (t_end, indices, [sha256 of each image], errors)
        self.before_done = threading.Event()
        self.failure = None

    def one(self):
        res = self.sc.redirect(TARGETS)
        self.requests.append((time.monotonic(), [r.index for r in res],
                              [hashlib.sha256(r.image.data).hexdigest() for r in res],
                              [repr(e) for e in self.sc.errors]))

    def run(self):
        try:
            for _ in range(BEFORE):
                self.one()
            self.before_done.set()
            # Keep the load on while the kill comes, then AFTER more.
            while not self.killed.is_set():
                self.one()
            for _ in range(AFTER):
                self.one()
        except Exception as e:  # noqa: BLE001 (reported by the main thread)
            self.failure = e
            self.before_done.set()
        finally:
            self.sc.close()


def main():
    daemon, cli = os.path.abspath(sys.argv[1]), os.path.abspath(sys.argv[2])
    os.makedirs(sys.argv[3], exist_ok=True)
    t = Checks()
    root = workdir("gs_scale_fo_")
    faces = synth_faces(cli, sys.argv[3], SUBJECTS)
    ds = [TcpDaemon(daemon, "d%d" % i, root) for i in (1, 2, 3)]
    hap = Haproxy(root, [(d.name, d.port) for d in ds])
    finished = False
    try:
        for d in ds:
            d.start()
        for d in ds:
            with Client(d.addr) as c:
                c.wait_ready()
        hap.start()
        st = hap.wait_status({d.name: "UP" for d in ds})
        t.check(all(st[d.name]["status"] == "UP" for d in ds), "three UP: %s" % st)
        keys = [subject_key(f, max_iters=ITERS) for f in faces]
        for f, k in zip(faces, keys):
            with SubjectClient(hap.addr, f, key=k, max_iters=ITERS) as sc:
                sc.fit()
        where = held(ds)
        home = {k: home_of(where, k) for k in keys}
        t.check(all(isinstance(h, str) for h in home.values()), "one home each: %s" % home)
        victim = max(ds, key=lambda d: len(where[d.name]))
        moved = [k for k in keys if home[k] == victim.name]
        stay = [k for k in keys if home[k] != victim.name]
        print("placement:", {n: len(s) for n, s in where.items()}, "victim", victim.name,
              "with", len(moved), "subjects")
        fits0 = {}
        for d in ds:
            with Client(d.addr) as c:
                fits0[d.name] = c.stats()["fits"]

        killed = threading.Event()
        ws = [Worker(hap.addr, f, k, killed) for f, k in zip(faces, keys)]
        for w in ws:
            w.start()
        for w in ws:
            w.before_done.wait(120)
        victim.kill()
        t_kill = time.monotonic()
        victim.proc.wait()
        killed.set()
        for w in ws:
            w.join(180)
            t.check(not w.is_alive(), "worker %s finished" % w.sc.key.hex()[:8])
            t.check(w.failure is None, "worker %s: %r" % (w.sc.key.hex()[:8], w.failure))

        # Every request: each target once, in order, the subject's bytes.
        total = lost = dup = errs = 0
        for w in ws:
            ref = w.requests[0][2] if w.requests else None
            for (_t, idx, sums, errors) in w.requests:
                total += 1
                lost += len(set(range(len(TARGETS))) - set(idx))
                dup += len(idx) - len(set(idx))
                errs += len(errors)
                t.check(idx == list(range(len(TARGETS))), "indices %s" % idx)
                t.check(sums == ref, "subject %s: the same images after the kill" % w.sc.key.hex()[:8])
                t.check(len(errors) <= 1, "at most one retryable error: %s" % errors)
        print("requests %d, images lost %d, duplicated %d, retryable errors %d" % (total, lost, dup, errs))
        t.check(lost == 0 and dup == 0, "no image lost or duplicated")

        # Time from the kill to each moved subject's first good response.
        for w in ws:
            if w.sc.key in moved:
                after = [r[0] - t_kill for r in w.requests if r[0] > t_kill]
                print("moved subject %s: first good response %.2f s after the kill, %d refit(s)"
                      % (w.sc.key.hex()[:8], after[0] if after else -1, w.sc.refits))
            t.check(w.sc.refits == (1 if w.sc.key in moved else 0),
                    "subject %s refitted %d times" % (w.sc.key.hex()[:8], w.sc.refits))

        # The ring now: the moved subjects on one survivor each, the others
        # where they were, and no fit but the moved subjects' refits.
        alive = [d for d in ds if d is not victim]
        now = held(alive)
        for k in moved:
            h = home_of(now, k)
            t.check(isinstance(h, str), "moved subject %s held by one survivor: %s" % (k.hex()[:8], h))
        for k in stay:
            t.check(home_of(now, k) == home[k], "subject %s stayed on %s: %s"
                    % (k.hex()[:8], home[k], home_of(now, k)))
        refits = 0
        for d in alive:
            with Client(d.addr) as c:
                refits += c.stats()["fits"] - fits0[d.name]
        t.check(refits == len(moved), "fits after the kill: %d, want %d" % (refits, len(moved)))
        finished = True
    finally:
        hap.stop()
        for d in ds:
            d.stop()
        if t.failures or not finished:
            for d in ds:
                print("---- %s log (tail) ----\n%s" % (d.name, d.log()[-2000:]))
            print("---- haproxy log ----\n" + hap.log()[-3000:])
        else:
            shutil.rmtree(root, ignore_errors=True)
    return t.status()


if __name__ == "__main__":
    sys.exit(main())
