"""Subject affinity through HAProxy (the shipped deploy/haproxy config) in
front of three daemons on loopback, plus a fourth whose model is missing
(HEALTH says FAILED): every connection of a subject, whatever it carries
(its FIT, each REDIRECT, each on a new connection), reaches the daemon that
holds the subject; the daemons' own counters and their HEALTH subject lists
say so; the failed daemon is never UP and takes nothing; a daemon that is
DRAINING is taken out and its subjects' new connections go elsewhere.
usage: test_scale_affinity.py GAZESPLATD GAZESPLAT_CLI WORKDIR"""
import os
import shutil
import signal
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from scale_util import Checks, Haproxy, TcpDaemon, digest_of, synth_faces, workdir  # noqa: E402
from gazesplat import Client, GazesplatError, pb  # noqa: E402
from gazesplat.routing import SubjectClient, subject_key  # noqa: E402

SUBJECTS = 6
REDIRECTS = 4        # per subject, each on its own connection
ITERS = 3            # fit iterations: the test checks routing, not quality
TARGETS = [(10, 0), (0, 15)]


def held(daemons):
    """{daemon name: set of keys} from HEALTH list_subjects, and checks of
    the count and the digest against the list."""
    out, bad = {}, []
    for d in daemons:
        with Client(d.addr) as c:
            h = c.health(list_subjects=True)
        keys = set(bytes(k) for k in h.subject_keys)
        out[d.name] = keys
        if h.subjects != len(keys) or bytes(h.subjects_digest) != digest_of(keys):
            bad.append(d.name)
    return out, bad


def main():
    daemon, cli = os.path.abspath(sys.argv[1]), os.path.abspath(sys.argv[2])
    os.makedirs(sys.argv[3], exist_ok=True)
    t = Checks()
    root = workdir("gs_scale_aff_")
    faces = synth_faces(cli, sys.argv[3], SUBJECTS)
    ds = [TcpDaemon(daemon, "d%d" % i, root, extra=["--set", "debug_requests=yes",
                                                    "--set", "drain_timeout_ms=60000"])
          for i in (1, 2, 3)]
    bad = TcpDaemon(daemon, "d4", root, model=os.path.join(root, "missing.safetensors"))
    hap = Haproxy(root, [(d.name, d.port) for d in ds + [bad]])
    finished = False
    try:
        for d in ds + [bad]:
            d.start()
        for d in ds:
            with Client(d.addr) as c:
                c.wait_ready()
        hap.start()
        # HAProxy starts with every server UP; the FAILED one goes DOWN
        # after its first failed checks (fall 2).
        st = hap.wait_status({"d1": "UP", "d2": "UP", "d3": "UP", "d4": "DOWN"})
        t.check(all(st[n]["status"] == "UP" for n in ("d1", "d2", "d3")), "three UP: %s" % st)
        with Client(bad.addr) as c:
            h = c.health()
        t.check(h.state == pb.Health.FAILED, "d4 FAILED: %s" % pb.Health.State.Name(h.state))
        t.check(st["d4"]["status"] == "DOWN", "the FAILED daemon is DOWN: %s" % st["d4"])

        keys = [subject_key(f, max_iters=ITERS) for f in faces]
        # The FIT of each subject on its own connection.
        for f, k in zip(faces, keys):
            with SubjectClient(hap.addr, f, key=k, max_iters=ITERS) as sc:
                r = sc.fit()
                t.check(not r.cached and bytes(r.subject_key) == k, "fit %s: %s" % (k.hex()[:8], r))
        where, wrong = held(ds)
        t.check(not wrong, "HEALTH subjects/digest agree with the lists: %s" % wrong)
        home = {}
        for k in keys:
            at = [n for n, s in where.items() if k in s]
            t.check(len(at) == 1, "subject %s held by one daemon: %s" % (k.hex()[:8], at))
            home[k] = at[0] if at else None
        print("placement:", {n: len(s) for n, s in where.items()})

        # REDIRECTs by key, each on a new connection that opens with the
        # key: a plain Client, so a miss would show (ERR_UNKNOWN_SUBJECT).
        hits = misses = 0
        for _ in range(REDIRECTS):
            for k in keys:
                try:
                    with Client(hap.addr, route_key=k) as c:
                        got = [res.index for res in c.redirect(TARGETS, subject=k)]
                    hits += got == [0, 1]
                except GazesplatError as e:
                    misses += 1
                    t.check(False, "redirect %s: %s" % (k.hex()[:8], e))
        n = SUBJECTS * REDIRECTS
        print("redirects: %d hit a cached subject, %d missed (of %d)" % (hits, misses, n))
        t.check(hits == n, "every REDIRECT met its subject: %d of %d" % (hits, n))

        # Each daemon's own counters: one fit per subject it holds, and the
        # REDIRECTs of exactly those subjects, all answered from its cache.
        for d in ds:
            with Client(d.addr) as c:
                s = c.stats()
            mine = sum(1 for k in keys if home[k] == d.name)
            t.check(s["fits"] == mine and s["fits_cached"] == 0,
                    "%s: fits %d (want %d), cached %d" % (d.name, s["fits"], mine, s["fits_cached"]))
            t.check(s["req_redirect"] == mine * REDIRECTS and s["request_errors"] == 0,
                    "%s: %d REDIRECTs (want %d), %d request errors"
                    % (d.name, s["req_redirect"], mine * REDIRECTS, s["request_errors"]))
            t.check(s["cache_hits"] >= mine * REDIRECTS, "%s: cache hits %d" % (d.name, s["cache_hits"]))
        with Client(bad.addr) as c:
            s = c.stats()
        t.check(s["req_fit"] == 0 and s["req_redirect"] == 0, "the FAILED daemon got no work: %s"
                % {k: s[k] for k in ("req_fit", "req_redirect")})

        # DRAINING: a daemon held in its drain by a running SLEEP fails
        # its checks; its subjects' new connections go to the others.
        victim = max(ds, key=lambda d: len(where[d.name]))
        slow = Client(victim.addr)
        rid = slow.new_id()
        slow.send(pb.FrameType.FRAME_SLEEP, pb.Sleep(ms=20000), rid)
        time.sleep(0.2)
        victim.kill(signal.SIGTERM)
        st = hap.wait_status({victim.name: "DOWN"})
        t.check(st[victim.name]["status"] == "DOWN", "draining %s is DOWN: %s"
                % (victim.name, st[victim.name]))
        moved = [k for k in keys if home[k] == victim.name]
        for k in moved:
            with Client(hap.addr, route_key=k) as c:
                h = c.health()
            t.check(h.state == pb.Health.READY, "subject %s now on a READY daemon" % k.hex()[:8])
        before = {n: v["stot"] for n, v in hap.servers().items()}
        for k in moved:
            with Client(hap.addr, route_key=k) as c:
                c.health()
        after = {n: v["stot"] for n, v in hap.servers().items()}
        t.check(after[victim.name] == before[victim.name],
                "no connection to the draining daemon: %s -> %s" % (before, after))
        slow.close()
        finished = True
    finally:
        hap.stop()
        for d in ds + [bad]:
            d.stop()
        if t.failures or not finished:
            for d in ds + [bad]:
                print("---- %s log (tail) ----\n%s" % (d.name, d.log()[-3000:]))
            print("---- haproxy log ----\n" + hap.log()[-3000:])
        else:
            shutil.rmtree(root, ignore_errors=True)
    return t.status()


if __name__ == "__main__":
    sys.exit(main())
