#!/usr/bin/python3
"""Scale-out figures (docs/scale-out.md): N daemons on loopback behind
HAProxy with the shipped deploy/haproxy config.

1. Cache hit rate of REDIRECTs by key, each on a new connection, after one
   FIT per subject: the shipped consistent hash on the subject key against
   the same config with `balance roundrobin`.
2. Failover: one thread per subject sending REDIRECTs through
   gazesplat.routing.SubjectClient; SIGKILL of the daemon holding the most
   subjects; time from the kill to each moved subject's first good
   response, against the fit time; images lost or duplicated; retryable
   errors seen.

usage: PYTHONPATH=build/python bench/daemon/scale_bench.py GAZESPLATD GAZESPLAT_CLI
       [--daemons 3] [--subjects 12] [--redirects 10] [--iters 3]"""
import argparse
import os
import random
import shutil
import statistics
import sys
import threading
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "..", "tests", "scale"))
from scale_util import Haproxy, TcpDaemon, synth_faces, workdir  # noqa: E402
from gazesplat import Client, GazesplatError  # noqa: E402
from gazesplat.routing import SubjectClient, subject_key  # noqa: E402

TARGETS = [(10, 0), (0, 15), (-10, -20)]


def rig(a, root, balance=None):
    ds = [TcpDaemon(a.daemon, "d%d" % i, root) for i in range(1, a.daemons + 1)]
    for d in ds:
        d.start()
    for d in ds:
        with Client(d.addr) as c:
            c.wait_ready()
    hap = Haproxy(root, [(d.name, d.port) for d in ds], balance=balance).start()
    hap.wait_status({d.name: "UP" for d in ds})
    return ds, hap


def teardown(ds, hap):
    hap.stop()
    for d in ds:
        d.stop()


def hit_rate(a, faces, balance):
    root = workdir("gs_scale_bench_")
    ds, hap = rig(a, root, balance)
    try:
        keys = [subject_key(f, max_iters=a.iters) for f in faces]
        for f, k in zip(faces, keys):
            with SubjectClient(hap.addr, f, key=k, max_iters=a.iters) as sc:
                sc.fit()
        hits = total = 0
        for rnd in range(a.redirects):
            # Shuffled: in key order, round-robin would line up with the FITs.
            for k in random.Random(rnd).sample(keys, len(keys)):
                total += 1
                try:
                    with Client(hap.addr, route_key=k) as c:
                        list(c.redirect(TARGETS[:1], subject=k))
                    hits += 1
                except GazesplatError:
                    pass
        held = []
        for d in ds:
            with Client(d.addr) as c:
                held.append(c.health().subjects)
        return hits, total, held
    finally:
        teardown(ds, hap)
        shutil.rmtree(root, ignore_errors=True)


def failover(a, faces):
    root = workdir("gs_scale_bench_")
    ds, hap = rig(a, root)
    try:
        keys = [subject_key(f, max_iters=a.iters) for f in faces]
        fit_s = []
        for f, k in zip(faces, keys):
            with SubjectClient(hap.addr, f, key=k, max_iters=a.iters) as sc:
                t0 = time.monotonic()
                sc.fit()
                fit_s.append(time.monotonic() - t0)
        where = {}
        for d in ds:
            with Client(d.addr) as c:
                for k in c.health(list_subjects=True).subject_keys:
                    where[bytes(k)] = d.name
        victim = max(ds, key=lambda d: sum(1 for v in where.values() if v == d.name))
        moved = {k for k in keys if where.get(k) == victim.name}
        stop = threading.Event()
        killed_at = [None]
        log = {k: [] for k in keys}  # (t_end, indices, errors)
        refit = {}  # moved subject: the server's seconds for its refit

        def work(f, k):
            with SubjectClient(hap.addr, f, key=k, max_iters=a.iters) as sc:
                while not stop.is_set():
                    res = sc.redirect(TARGETS)
                    log[k].append((time.monotonic(), [r.index for r in res], len(sc.errors)))
                    if sc.refits and k not in refit:
                        refit[k] = sc.last_fit.seconds

        ts = [threading.Thread(target=work, args=(f, k), daemon=True) for f, k in zip(faces, keys)]
        for t in ts:
            t.start()
        time.sleep(2.0)
        victim.kill()
        killed_at[0] = time.monotonic()
        time.sleep(4.0)
        stop.set()
        for t in ts:
            t.join(60)
        first = []
        for k in moved:
            after = [e[0] - killed_at[0] for e in log[k] if e[0] > killed_at[0]]
            if after:
                first.append((after[0], refit.get(k, float("nan"))))
        reqs = [e for k in keys for e in log[k]]
        lost = sum(len(set(range(len(TARGETS))) - set(e[1])) for e in reqs)
        dup = sum(len(e[1]) - len(set(e[1])) for e in reqs)
        errs = [e[2] for e in reqs]
        return {"fit_s": statistics.median(fit_s), "moved": len(moved), "first": sorted(first),
                "requests": len(reqs), "lost": lost, "dup": dup, "errors": sum(errs),
                "max_errors": max(errs) if errs else 0}
    finally:
        teardown(ds, hap)
        shutil.rmtree(root, ignore_errors=True)


def main():
    p = argparse.ArgumentParser()
    p.add_argument("daemon")
    p.add_argument("cli")
    p.add_argument("--daemons", type=int, default=3)
    p.add_argument("--subjects", type=int, default=12)
    p.add_argument("--redirects", type=int, default=10)
    p.add_argument("--iters", type=int, default=3)
    a = p.parse_args()
    work = workdir("gs_scale_faces_")
    faces = synth_faces(a.cli, work, a.subjects)
    print("%d daemons, %d subjects, FIT max_iters %d, %d REDIRECTs per subject each on a new connection"
          % (a.daemons, a.subjects, a.iters, a.redirects))
    for balance, name in ((None, "consistent hash on the subject key"), ("roundrobin", "round-robin")):
        hits, total, held = hit_rate(a, faces, balance)
        print("%-36s REDIRECT cache hits %d/%d = %.1f %%; subjects per daemon %s"
              % (name + ":", hits, total, 100.0 * hits / total, held))
    r = failover(a, faces)
    print("failover (SIGKILL under load): %d subjects moved; fit %.2f s (median); first good response "
          "after the kill (its refit's server time) %s s; %d requests, %d images lost, %d duplicated, %d retryable errors "
          "(at most %d in one request)"
          % (r["moved"], r["fit_s"], ", ".join("%.2f (%.2f)" % x for x in r["first"]), r["requests"],
             r["lost"], r["dup"], r["errors"], r["max_errors"]))
    shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
