"""gazesplat augment sharded and merged (augment --merge), two modes:

  merge  no Slurm: N shards run one after another, merged: labels.jsonl,
         augment.h5 and the images are the unsharded run's bytes; the
         merge's refusals (a shard missing or unfinished, shards of two
         runs, a sample twice, bad usage) exit non-zero and say why.
  slurm  the deploy/slurm recipe on a one-node Slurm this test starts
         (munged, slurmctld, slurmd as plain processes, configs in a temp
         dir): submit.sh's job array and merge job give the unsharded
         run's bytes. Where Slurm cannot start, the batch scripts run as
         Slurm would run them (the array's variables set by hand), the
         reason is printed and the test exits 77 (skipped).

usage: test_slurm_augment.py GAZESPLAT_CLI WORKDIR merge|slurm"""
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.abspath(os.path.join(HERE, "..", ".."))
sys.path.insert(0, HERE)
from scale_util import MODEL, Checks, free_port, synth_faces  # noqa: E402

SLURM = os.path.join(ROOT, "deploy", "slurm")
SHARDS = 3
SOURCES = 5  # shards of 2, 2 and 1 sources


def augment_args(faces_dir):
    return ["--model", MODEL, "--input", faces_dir, "--gaze-deg", "10,0;0,15", "--iters", "3",
            "--finetune", "2", "--size", "64"]


def tree(d):
    """{relative path: bytes} of the files a run is compared on."""
    out = {}
    for name in ("labels.jsonl", "augment.h5"):
        p = os.path.join(d, name)
        if os.path.exists(p):
            out[name] = open(p, "rb").read()
    img = os.path.join(d, "images")
    for n in sorted(os.listdir(img)) if os.path.isdir(img) else []:
        out["images/" + n] = open(os.path.join(img, n), "rb").read()
    return out


def same(t, a, b, what):
    ta, tb = tree(a), tree(b)
    t.check(sorted(ta) == sorted(tb), "%s: files %s vs %s" % (what, sorted(ta)[:4], sorted(tb)[:4]))
    diff = [k for k in ta if k in tb and ta[k] != tb[k]]
    t.check(not diff and "labels.jsonl" in ta and "augment.h5" in ta,
            "%s: the unsharded run's bytes (differing: %s)" % (what, diff[:5]))


def run(cli, *args):
    return subprocess.run([cli, "augment"] + list(args), capture_output=True, text=True)


def prepare(cli, work):
    faces = os.path.join(work, "faces256_%d" % SOURCES)
    synth_faces(cli, work, SOURCES)
    ref = os.path.join(work, "unsharded")
    # Made afresh by every run: a reference left by an older build would
    # hold that build's labels.
    shutil.rmtree(ref, ignore_errors=True)
    r = run(cli, "--out", ref, "--threads", "2", *augment_args(os.path.join(faces, "images")))
    if r.returncode != 0:
        raise RuntimeError("unsharded run: %s" % r.stderr)
    return os.path.join(faces, "images"), ref


def merge_mode(t, cli, work):
    faces, ref = prepare(cli, work)
    out = tempfile.mkdtemp(prefix="gs_merge_", dir=work)
    for i in range(SHARDS):
        r = run(cli, "--out", out, "--shard", "%d/%d" % (i, SHARDS), *augment_args(faces))
        t.check(r.returncode == 0, "shard %d: %s" % (i, r.stderr[-500:]))
    r = run(cli, "--merge", str(SHARDS), "--out", out)
    t.check(r.returncode == 0 and "merged 3 shards: 10 images" in r.stdout, "merge: %s %s"
            % (r.stdout, r.stderr))
    same(t, ref, out, "merged")
    r = run(cli, "--merge", str(SHARDS), "--out", out)
    t.check(r.returncode == 0, "a second merge: %s" % r.stderr)
    same(t, ref, out, "merged twice")

    def refused(args, rc, text, what):
        r = run(cli, *args)
        t.check(r.returncode == rc and text in r.stderr, "%s: exit %d, %r" % (what, r.returncode,
                                                                            r.stderr.strip()[-300:]))

    refused(["--merge", "1", "--out", out], 2, "2 or more", "--merge 1")
    refused(["--merge", "x", "--out", out], 2, "number of shards", "--merge x")
    refused(["--merge", "3"], 2, "needs --out", "--merge without --out")
    refused(["--merge", "3", "--out", out, "--model", MODEL], 2, "not --model", "--merge with --model")
    refused(["--merge", "4", "--out", out], 1, "is shard 0/4", "a shard missing")
    # An unfinished shard: its manifest without the closing line.
    man = os.path.join(out, ".augment-1-of-3", "manifest")
    text = open(man).read()
    open(man, "w").write(text.replace("finished\n", ""))
    refused(["--merge", "3", "--out", out], 1, "is not finished", "an unfinished shard")
    open(man, "w").write(text)
    # Shards of two runs: another target count in one manifest.
    head, rest = text.split("\n", 1)
    f = head.split(" ")
    open(man, "w").write(" ".join(f[:-1] + [str(int(f[-1]) + 1)]) + "\n" + rest)
    refused(["--merge", "3", "--out", out], 1, "not shards of one run", "shards of two runs")
    open(man, "w").write(text)
    # A sample twice: shard 0's first line copied into shard 1's labels.
    lab0, lab1 = (os.path.join(out, "labels-%d-of-3.jsonl" % i) for i in (0, 1))
    keep = open(lab1).read()
    open(lab1, "w").write(open(lab0).readline() + keep)
    refused(["--merge", "3", "--out", out], 1, "also in shard", "a sample twice")
    open(lab1, "w").write(keep)
    # HDF5 in some shards only.
    h5 = os.path.join(out, "augment-2-of-3.h5")
    os.rename(h5, h5 + ".away")
    refused(["--merge", "3", "--out", out], 1, "all or none", "HDF5 in two shards of three")
    os.rename(h5 + ".away", h5)
    r = run(cli, "--merge", str(SHARDS), "--out", out)
    t.check(r.returncode == 0, "merge after the repairs: %s" % r.stderr)
    same(t, ref, out, "merged after the refusals")
    shutil.rmtree(out, ignore_errors=True)


class Slurm:
    """munged, slurmctld and slurmd of a one-node cluster in a temp dir."""

    def __init__(self, root):
        self.dir = root
        self.procs = []
        self.node = socket.gethostname().split(".")[0]
        self.env = dict(os.environ, SLURM_CONF=os.path.join(root, "slurm.conf"))

    def spawn(self, name, argv):
        log = open(os.path.join(self.dir, name + ".out"), "wb")
        p = subprocess.Popen(argv, stdout=log, stderr=log, env=self.env)
        log.close()
        self.procs.append((name, p))
        return p

    def start(self):
        d = self.dir
        for sub in ("state", "spool"):
            os.makedirs(os.path.join(d, sub), exist_ok=True)
        key = os.path.join(d, "munge.key")
        with open(key, "wb") as f:
            f.write(os.urandom(1024))
        os.chmod(key, 0o400)
        sock = os.path.join(d, "munge.sock")
        self.spawn("munged", ["munged", "-F", "--socket=" + sock, "--key-file=" + key,
                              "--pid-file=" + os.path.join(d, "munged.pid"),
                              "--log-file=" + os.path.join(d, "munged.log"),
                              "--seed-file=" + os.path.join(d, "munged.seed")])
        end = time.time() + 10
        while not os.path.exists(sock) and time.time() < end:
            time.sleep(0.05)
        if not os.path.exists(sock):
            return "munged did not start: " + self.tail("munged")
        conf = "\n".join([
            "ClusterName=gstest",
            "SlurmctldHost=%s(127.0.0.1)" % self.node,
            "SlurmUser=root", "SlurmdUser=root",
            "SlurmctldPort=%d" % free_port(), "SlurmdPort=%d" % free_port(),
            "AuthType=auth/munge", "CredType=cred/munge", "AuthInfo=socket=" + sock,
            "StateSaveLocation=" + os.path.join(d, "state"),
            "SlurmdSpoolDir=" + os.path.join(d, "spool"),
            "SlurmctldPidFile=" + os.path.join(d, "slurmctld.pid"),
            "SlurmdPidFile=" + os.path.join(d, "slurmd.pid"),
            "SlurmctldLogFile=" + os.path.join(d, "slurmctld.log"),
            "SlurmdLogFile=" + os.path.join(d, "slurmd.log"),
            # No cgroups, no accounting: plain processes in a container.
            "ProctrackType=proctrack/linuxproc", "TaskPlugin=task/none", "SwitchType=switch/none",
            "MpiDefault=none", "JobAcctGatherType=jobacct_gather/none",
            "AccountingStorageType=accounting_storage/none", "JobCompType=jobcomp/none",
            "SchedulerType=sched/backfill", "SelectType=select/cons_tres",
            "SelectTypeParameters=CR_Core", "ReturnToService=2", "MailProg=/bin/true",
            "NodeName=%s NodeAddr=127.0.0.1 CPUs=2 RealMemory=1000 State=UNKNOWN" % self.node,
            "PartitionName=test Nodes=%s Default=YES MaxTime=INFINITE State=UP" % self.node, ""])
        with open(self.env["SLURM_CONF"], "w") as f:
            f.write(conf)
        self.spawn("slurmctld", ["slurmctld", "-D", "-f", self.env["SLURM_CONF"]])
        self.spawn("slurmd", ["slurmd", "-D", "-f", self.env["SLURM_CONF"]])
        end = time.time() + 40
        while time.time() < end:
            for name, p in self.procs:
                if p.poll() is not None:
                    return "%s exited with %s: %s" % (name, p.returncode, self.tail(name))
            r = subprocess.run(["sinfo", "-h", "-o", "%T"], capture_output=True, text=True, env=self.env)
            if r.returncode == 0 and r.stdout.strip() == "idle":
                return None
            time.sleep(0.2)
        return "the node never became idle: sinfo %r; %s" % (r.stdout + r.stderr, self.tail("slurmd"))

    def tail(self, name):
        for p in (os.path.join(self.dir, name + ".log"), os.path.join(self.dir, name + ".out")):
            if os.path.exists(p) and os.path.getsize(p):
                return open(p, errors="replace").read()[-1500:]
        return "(no log)"

    def state(self, job):
        r = subprocess.run(["scontrol", "show", "job", job], capture_output=True, text=True, env=self.env)
        for tok in r.stdout.split():
            if tok.startswith("JobState="):
                return tok[len("JobState="):]
        return None

    def stop(self):
        for name, p in reversed(self.procs):
            if p.poll() is None:
                p.terminate()
                try:
                    p.wait(15)
                except subprocess.TimeoutExpired:
                    p.kill()
                    p.wait()


def by_hand(t, cli, faces, out):
    """The batch scripts as Slurm runs them, without Slurm."""
    env = dict(os.environ, GAZESPLAT=cli, GS_OUT=out, SLURM_ARRAY_TASK_COUNT=str(SHARDS),
               SLURM_ARRAY_TASK_MIN="0", SLURM_ARRAY_TASK_MAX=str(SHARDS - 1),
               SLURM_ARRAY_TASK_STEP="1", SLURM_CPUS_PER_TASK="2")
    for i in range(SHARDS):
        env["SLURM_ARRAY_TASK_ID"] = str(i)
        r = subprocess.run([os.path.join(SLURM, "augment.sbatch")] + augment_args(faces), env=env,
                           capture_output=True, text=True)
        t.check(r.returncode == 0, "augment.sbatch task %d: %s" % (i, r.stderr[-400:]))
    env["GS_SHARDS"] = str(SHARDS)
    r = subprocess.run([os.path.join(SLURM, "merge.sbatch")], env=env, capture_output=True, text=True)
    t.check(r.returncode == 0, "merge.sbatch: %s" % r.stderr[-400:])


def slurm_mode(t, cli, work):
    for prog in ("munged", "slurmctld", "slurmd", "sbatch", "sinfo", "scontrol"):
        if shutil.which(prog) is None:
            t.check(False, "%s is not installed (scripts/install-deps.sh: slurm-wlm, munge)" % prog)
            return 1
    faces, ref = prepare(cli, work)
    root = tempfile.mkdtemp(prefix="gs_slurm_")
    os.chmod(root, 0o755)  # munged wants its socket's folder searchable by all
    out = os.path.join(root, "out")
    sl = Slurm(root)
    ok = False
    try:
        # GS_TEST_SLURM_BY_HAND=1 takes the no-Slurm path (to test it).
        why = sl.start() if not os.environ.get("GS_TEST_SLURM_BY_HAND") else "GS_TEST_SLURM_BY_HAND"
        if why is not None:
            print("Slurm could not start here: %s" % why)
            by_hand(t, cli, faces, out)
            same(t, ref, out, "the batch scripts run by hand")
            ok = True
            return 77 if t.failures == 0 else 1
        env = dict(sl.env, GAZESPLAT=cli)
        r = subprocess.run([os.path.join(SLURM, "submit.sh"), str(SHARDS), out] + augment_args(faces),
                           capture_output=True, text=True, env=env, cwd=root)
        t.check(r.returncode == 0 and len(r.stdout.split()) == 2, "submit.sh: %r %r" % (r.stdout, r.stderr))
        if r.returncode == 0:
            array, merge = r.stdout.split()
            end = time.time() + 240
            while time.time() < end and sl.state(merge) not in ("COMPLETED", "FAILED", "CANCELLED",
                                                                "TIMEOUT", "NODE_FAIL", "OUT_OF_MEMORY"):
                time.sleep(0.5)
            states = [sl.state("%s_%d" % (array, i)) for i in range(SHARDS)]
            t.check(states == ["COMPLETED"] * SHARDS, "array tasks: %s" % states)
            t.check(sl.state(merge) == "COMPLETED", "merge job: %s" % sl.state(merge))
            same(t, ref, out, "Slurm array + merge")
        ok = True
    finally:
        sl.stop()
        if t.failures or not ok:
            for name in ("slurmctld", "slurmd", "munged"):
                print("---- %s ----\n%s" % (name, sl.tail(name)))
            for n in sorted(os.listdir(root)):
                if n.startswith("slurm-"):
                    print("---- %s ----\n%s" % (n, open(os.path.join(root, n)).read()[-1500:]))
        else:
            shutil.rmtree(root, ignore_errors=True)
    return None


def main():
    cli, work, mode = os.path.abspath(sys.argv[1]), os.path.abspath(sys.argv[2]), sys.argv[3]
    os.makedirs(work, exist_ok=True)
    t = Checks()
    if mode == "merge":
        merge_mode(t, cli, work)
    elif mode == "slurm":
        rc = slurm_mode(t, cli, work)
        if rc is not None:
            t.status()
            return rc
    else:
        raise SystemExit("mode: merge or slurm")
    return t.status()


if __name__ == "__main__":
    sys.exit(main())
