"""gazesplat augment --addr through HAProxy (the shipped deploy/haproxy
config) in front of three daemons on loopback: each source goes on its own
connection opening with the source's route key, so the sources spread over
the daemons, every FIT and its REDIRECTs meet on one daemon, and a rerun
finds every subject cached where it was fitted, with the same bytes. Then kill -9 of the daemon
fitting a source, mid-run: augment fits that source again where the proxy
sends it next and ends with exit 0 and the bytes of a run against one
daemon that nobody killed (nothing lost, nothing twice).
usage: test_scale_augment.py GAZESPLATD GAZESPLAT_CLI WORKDIR"""
import filecmp
import os
import shutil
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from scale_util import Checks, Haproxy, TcpDaemon, synth_faces, workdir  # noqa: E402
from gazesplat import Client  # noqa: E402

SOURCES = 6
TARGETS = "10,0;0,15"
FIT_A = ["--iters", "3", "--finetune", "0"]    # routing: cheap fits
FIT_B = ["--iters", "20", "--finetune", "2"]   # failover: a fit long enough to be cut


def augment(cli, addr, src, out, fit, extra=(), wait=True):
    argv = [cli, "augment", "--addr", addr, "--input", src, "--out", out,
            "--gaze-deg", TARGETS] + fit + list(extra)
    if not wait:
        return subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    return subprocess.run(argv, capture_output=True, text=True, timeout=600)


def same_tree(a, b):
    """Names of the files that differ between the two outputs (labels,
    images, HDF5), or are in one only."""
    bad = []
    for rel in ["labels.jsonl", "augment.h5"] + [
            os.path.join("images", n) for n in sorted(os.listdir(os.path.join(a, "images")))]:
        pa, pb_ = os.path.join(a, rel), os.path.join(b, rel)
        if not (os.path.exists(pb_) and filecmp.cmp(pa, pb_, shallow=False)):
            bad.append(rel)
    if sorted(os.listdir(os.path.join(a, "images"))) != sorted(os.listdir(os.path.join(b, "images"))):
        bad.append("images/ (names)")
    return bad


def stats(ds):
    out = {}
    for d in ds:
        if d.proc is None or d.proc.poll() is not None:
            continue
        with Client(d.addr) as c:
            out[d.name] = c.stats()
    return out


def main():
    daemon, cli = os.path.abspath(sys.argv[1]), os.path.abspath(sys.argv[2])
    os.makedirs(sys.argv[3], exist_ok=True)
    t = Checks()
    root = workdir("gs_scale_aug_")
    src = os.path.join(root, "faces")
    os.makedirs(src)
    for i, png in enumerate(synth_faces(cli, sys.argv[3], SOURCES)):
        with open(os.path.join(src, "face%02d.png" % i), "wb") as f:
            f.write(png)
    alone = TcpDaemon(daemon, "d0", root)
    ds = [TcpDaemon(daemon, "d%d" % i, root) for i in (1, 2, 3)]
    hap = Haproxy(root, [(d.name, d.port) for d in ds])
    finished = False
    try:
        for d in [alone] + ds:
            d.start()
        for d in [alone] + ds:
            with Client(d.addr) as c:
                c.wait_ready()
        hap.start()
        st = hap.wait_status({"d1": "UP", "d2": "UP", "d3": "UP"})
        t.check(all(st[n]["status"] == "UP" for n in ("d1", "d2", "d3")), "three UP: %s" % st)

        # The references: one daemon, nobody killed.
        for name, fit in (("ref_a", FIT_A), ("ref_b", FIT_B)):
            r = augment(cli, alone.addr, src, os.path.join(root, name), fit)
            t.check(r.returncode == 0, "%s: exit %d: %s" % (name, r.returncode, r.stderr[-800:]))

        # Affinity: the sources spread, each fitted once, the bytes of one daemon.
        r = augment(cli, hap.addr, src, os.path.join(root, "a"), FIT_A)
        t.check(r.returncode == 0, "through the proxy: exit %d: %s" % (r.returncode, r.stderr[-800:]))
        diff = same_tree(os.path.join(root, "ref_a"), os.path.join(root, "a"))
        t.check(not diff, "through the proxy: the one daemon's bytes (differ: %s)" % diff[:5])
        s1 = stats(ds)
        fits = {n: s["fits"] for n, s in s1.items()}
        print("fits per daemon:", fits)
        t.check(sum(fits.values()) == SOURCES, "one fit per source in all: %s" % fits)
        t.check(sum(1 for v in fits.values() if v) >= 2, "the sources spread: %s" % fits)
        t.check(all(s["request_errors"] == 0 for s in s1.values()), "no request errors")
        # A rerun into a new folder: every FIT meets its subject in the
        # cache of the daemon that fitted it.
        r = augment(cli, hap.addr, src, os.path.join(root, "a2"), FIT_A)
        t.check(r.returncode == 0, "rerun: exit %d: %s" % (r.returncode, r.stderr[-800:]))
        s2 = stats(ds)
        cached = {n: s2[n]["fits_cached"] - s1[n]["fits_cached"] for n in s2}
        refit = {n: s2[n]["fits"] - s1[n]["fits"] for n in s2}
        print("rerun: cached FITs per daemon:", cached, "new fits:", refit)
        t.check(sum(cached.values()) == SOURCES and not any(refit.values()),
                "rerun: every FIT cached where it was fitted (cached %s, new %s)" % (cached, refit))
        # The same bytes: a render depends on the subject and the view alone
        # (each incremental render starts from the subject's render at its
        # own gaze, never from the last target: docs/model.md, "Gaze sweeps").
        diff = same_tree(os.path.join(root, "ref_a"), os.path.join(root, "a2"))
        t.check(not diff, "rerun: the same bytes (differ: %s)" % diff[:5])

        # Failover: kill -9 the daemon that is fitting, while it fits.
        base = stats(ds)
        p = augment(cli, hap.addr, src, os.path.join(root, "b"), FIT_B, wait=False)
        victim, end = None, time.time() + 120
        while victim is None and time.time() < end and p.poll() is None:
            for d in ds:
                with Client(d.addr) as c:
                    s = c.stats()
                if s["jobs_running"] > 0 and s["req_fit"] > base[d.name]["req_fit"]:
                    victim = d
                    break
            time.sleep(0.02)
        t.check(victim is not None, "caught a daemon fitting")
        if victim is not None:
            victim.kill()
            print("killed %s mid-fit" % victim.name)
        out, err = p.communicate(timeout=600)
        t.check(p.returncode == 0, "failover: exit %d: %s" % (p.returncode, err[-1500:]))
        t.check("trying again" in err, "failover: the cut source was tried again: %s" % err[-600:])
        diff = same_tree(os.path.join(root, "ref_b"), os.path.join(root, "b"))
        t.check(not diff, "failover: the bytes of the uncut run (differ: %s)" % diff[:5])
        with open(os.path.join(root, "b", "labels.jsonl")) as f:
            n = sum(1 for _ in f)
        t.check(n == SOURCES * 2, "failover: %d labels (want %d)" % (n, SOURCES * 2))
        finished = True
    finally:
        hap.stop()
        for d in [alone] + ds:
            d.stop()
        if t.failures or not finished:
            for d in [alone] + ds:
                print("---- %s log (tail) ----\n%s" % (d.name, d.log()[-2000:]))
            print("---- haproxy log ----\n" + hap.log()[-2000:])
        else:
            shutil.rmtree(root, ignore_errors=True)
    return t.status()


if __name__ == "__main__":
    sys.exit(main())
