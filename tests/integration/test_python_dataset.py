"""The PyTorch Dataset and the example training script against gazesplatd
with a tiny real model: shapes, ranges, exact target labels, two DataLoader
workers, and a few training steps. Samples come shuffled (sources mixed);
they are compared by (source, target).
usage: test_python_dataset.py GAZESPLATD GAZESPLAT_CLI WORKDIR"""
import math
import os
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
PYDIR = os.path.join(HERE, "..", "..", "clients", "python")
sys.path.insert(0, HERE)
sys.path.insert(0, PYDIR)
from daemon_util import Checks, Daemon  # noqa: E402
from model_fixture import faces, tiny_model  # noqa: E402


def main():
    daemon, cli, work = (os.path.abspath(a) for a in sys.argv[1:4])
    os.makedirs(work, exist_ok=True)
    t = Checks()
    model = tiny_model(cli, work, seed=1)
    faces(cli, work, 128, 3)
    paths = [os.path.join(work, "faces128", "images", n)
             for n in sorted(os.listdir(os.path.join(work, "faces128", "images")))]
    d = Daemon(daemon, ["--model", model, "--set", "photo_input=no", "--set", "input_cache_mb=1"]).start()
    try:
        import torch
        import gazesplat_client as gc
        from gazesplat_dataset import RedirectedGazeDataset
        addr = "unix:" + d.sock
        for _ in range(600):
            with gc.Client(addr) as c:
                if c.health().state == gc.pb.Health.READY:
                    break
            time.sleep(0.05)
        targets = [(0, 0), (10, -20), (-15, 25)]
        ds = RedirectedGazeDataset(paths[:2], gaze_targets=targets, head_targets=(0, 5), addr=addr,
                                   fit_iters=3, batch=2)
        def by_label(xs):
            return {(x["source"], tuple(round(v, 3) for v in x["gaze_head_deg"].tolist())): x for x in xs}

        samples = list(ds)
        t.check(len(samples) == 6 and len(by_label(samples)) == 6, "%d samples" % len(samples))
        s = by_label(samples).get((0, (10.0, -20.0)), samples[1])
        t.check(s["image"].shape == (3, 128, 128) and s["image"].dtype == torch.float32,
                "image %s %s" % (s["image"].shape, s["image"].dtype))
        t.check(0 <= float(s["image"].min()) and float(s["image"].max()) <= 1, "range")
        t.check(torch.allclose(s["gaze"], torch.tensor([10 * math.pi / 180, -20 * math.pi / 180])),
                "gaze label %s" % s["gaze"])
        t.check(torch.allclose(s["head"], torch.tensor([0.0, 5 * math.pi / 180])), "head %s" % s["head"])
        t.check(sorted({x["source"] for x in samples}) == [0, 1], "sources")
        # Detail transfer: the same labels, other pixels (the sources' own).
        xs = list(RedirectedGazeDataset(paths[:2], gaze_targets=targets, head_targets=(0, 5), addr=addr,
                                        fit_iters=3, batch=2, transfer=True))
        t.check(len(xs) == 6 and all(torch.equal(a["gaze"], b["gaze"]) for a, b in zip(xs, samples)),
                "transfer: same samples and labels, in the same (seeded) order")
        diff = max(float((a["image"] - b["image"]).abs().mean()) for a, b in zip(xs, samples))
        t.check(0.002 < diff and all(0 <= float(a["image"].min()) and float(a["image"].max()) <= 1
                                     for a in xs), "transfer images differ from plain (%.4f), in range"
                % diff)
        # A kept input evicted between the dataset's FIT and its REDIRECT
        # (a budget of 1 MiB holds 21 of these 128 px inputs; 24 other
        # subjects evict it) is fitted again and renders the same.
        xd = RedirectedGazeDataset(paths[:1], gaze_targets=targets, head_targets=(0, 5), addr=addr,
                                   fit_iters=3, batch=2, transfer=True)
        with gc.Client(addr) as c:
            fit0 = xd._fit(c, paths[0])
            for i in range(24):
                c.fit(open(paths[2], "rb").read(), key=bytes([9, i]) + bytes(14), max_iters=1,
                      keep_image=True)
            evicted = c.stats()["input_evictions"]
            try:
                list(c.redirect([(0, 0)], subject=fit0.subject_key, transfer=True))
                gone = None
            except gc.GazesplatError as e:
                gone = e.code
            t.check(gone == gc.pb.ERR_UNKNOWN_SUBJECT, "the source's kept input is evicted: %s" % gone)
            fits = c.stats()["fits"]
            ys = list(xd._render(c, fit0, 0, targets, [(0, 5)] * 3))
            t.check(c.stats()["fits"] == fits, "the refit was a cached FIT")
        x0 = by_label(xs)
        t.check(evicted >= 1 and len(ys) == 3 and all(torch.equal(a["image"], x0[k]["image"])
                                                      for k, a in by_label(ys).items()),
                "after %d evictions the dataset refits and renders the same" % evicted)
        loader = torch.utils.data.DataLoader(ds, batch_size=3, num_workers=2)
        n = sum(b["image"].shape[0] for b in loader)
        t.check(n == 6, "two workers: %d samples" % n)
        env = dict(os.environ)
        r = subprocess.run([sys.executable, os.path.join(PYDIR, "examples", "train_gaze_estimator.py"),
                            "--addr", addr, "--steps", "3", "--batch", "4", "--fit-iters", "3"] + paths,
                           capture_output=True, text=True, env=env, timeout=300)
        t.check(r.returncode == 0 and "trained 3 steps" in r.stdout,
                "example: rc %d\n%s\n%s" % (r.returncode, r.stdout[-2000:], r.stderr[-2000:]))
    finally:
        rc = d.stop()
        if t.failures:
            print(d.log()[-4000:])
    t.check(rc == 0, "exit %s" % rc)
    return t.status()


if __name__ == "__main__":
    sys.exit(main())
