"""Checks of the Python package gazesplat as installed (run by
test_python_package.py with the interpreter of a fresh venv it was
pip-installed into; nothing here comes from the source tree but the test
helpers daemon_util and model_fixture):
  * where it came from: the venv's site-packages, generated gazesplat_pb2,
    py.typed, the installed metadata (version, protobuf, the extra torch);
  * GazesplatError, Busy and ProtocolError pickle with their fields, and
    survive PyTorch's DataLoader worker re-raise with their code;
  * gazesplat.geometry: known cases, and the C library's own labels
    (lib/synth's gaze_cam = head_R gaze_head) from the faces fixture;
  * Client against the real daemon: FIT, REDIRECT; a redirect left early
    (break, close(), dropped, never started) is cancelled and drained and
    the connection serves the next request;
  * AsyncClient: concurrent FITs on one connection, REDIRECT streams, early
    exit, errors;
  * RedirectedGazeDataset: labels and metadata (head and camera gaze),
    sources mixed within batches, worker-count independence, set_epoch,
    photo inputs, deadline and timeout options, a server error through a
    DataLoader worker.
usage: package_checks.py GAZESPLATD GAZESPLAT_CLI WORKDIR SITE_PREFIX PHOTO"""
import asyncio
import contextlib
import gc as pygc
import importlib.metadata
import json
import math
import os
import pickle
import re
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.append(HERE)  # after site-packages: only the helpers come from here
from daemon_util import Checks, Daemon  # noqa: E402
from model_fixture import faces, tiny_model  # noqa: E402

import gazesplat  # noqa: E402
from gazesplat import Busy, Client, GazesplatError, ProtocolError, pb  # noqa: E402
from gazesplat import geometry  # noqa: E402
from gazesplat.aio import AsyncClient  # noqa: E402

FAR = [(p, y) for p in (-20, 0, 20) for y in range(-30, 31, 3)][:60]  # 60 targets


def check_install(t, prefix):
    pkg = os.path.dirname(os.path.abspath(gazesplat.__file__))
    t.check(pkg.startswith(os.path.abspath(prefix)), "gazesplat imported from %s, not under %s" % (pkg, prefix))
    t.check(os.path.dirname(os.path.abspath(pb.__file__)) == pkg and pb.__name__ == "gazesplat.gazesplat_pb2",
            "messages %s from %s" % (pb.__name__, pb.__file__))
    for f in ("py.typed", "gazesplat_pb2.pyi", "_version.py"):
        t.check(os.path.exists(os.path.join(pkg, f)), "installed package lacks %s" % f)
    v = importlib.metadata.version("gazesplat")
    t.check(v == gazesplat.__version__ and v[0].isdigit(), "metadata version %s, module %s" % (v, gazesplat.__version__))
    req = importlib.metadata.requires("gazesplat") or []
    t.check(any(r.startswith("protobuf") and "extra" not in r for r in req) and
            any(re.match(r"torch\W.*extra ?== ?.torch", r) for r in req), "requires %s" % req)
    eps = [e for e in importlib.metadata.entry_points(group="console_scripts") if e.name == "gazesplat-grid"]
    t.check(len(eps) == 1 and eps[0].value == "gazesplat.grid:cli", "entry point %s" % eps)
    m = pickle.loads(pickle.dumps(pb.Hello(client_name="x", min_version=1)))
    t.check(m.client_name == "x" and type(m).__module__ == "gazesplat.gazesplat_pb2", "message pickles")


def same_error(a, b):
    return (type(a) is type(b) and str(a) == str(b) and
            all(getattr(a, f, None) == getattr(b, f, None)
                for f in ("code", "name", "message", "request_id", "retry_after_ms", "queue_length")))


def check_pickle(t):
    for e in (GazesplatError(pb.ERR_DEADLINE, "deadline passed", 7), GazesplatError(999, "new code"),
              Busy(250, 16, 9), ProtocolError("bad magic from server")):
        r = pickle.loads(pickle.dumps(e))
        t.check(same_error(e, r), "pickle round trip %r -> %r" % (e, r))
    e = GazesplatError(pb.ERR_DEADLINE, "deadline passed", 7)
    t.check(e.code == 24 and e.name == "ERR_DEADLINE" and e.request_id == 7 and str(e) == "ERR_DEADLINE: deadline passed",
            "fields %r" % e)
    # What PyTorch's DataLoader does with a worker's exception.
    from torch._utils import ExceptionWrapper
    for e in (e, Busy(250, 16, 9)):
        try:
            raise e
        except Exception:
            w = pickle.loads(pickle.dumps(ExceptionWrapper(sys.exc_info(), where="in DataLoader worker process 0")))
        try:
            w.reraise()
        except (GazesplatError, Busy) as r:
            t.check(type(r) is type(e) and getattr(r, "code", None) == getattr(e, "code", None) and
                    getattr(r, "retry_after_ms", None) == getattr(e, "retry_after_ms", None),
                    "DataLoader re-raise of %r: %r" % (e, r))
        except Exception as r:
            t.check(False, "DataLoader re-raise of %r gave %r" % (e, r))


def close(a, b, tol=1e-6):
    return all(abs(x - y) < tol for x, y in zip(a, b))


def check_geometry(t, work):
    h2c = geometry.gaze_head_to_camera
    t.check(close(h2c((0, 0), (0, 0)), (0, 0)), "frontal")
    # Looking straight out of the face: the camera-frame gaze is the head pose.
    t.check(close(h2c((0, 0), (0, 30)), (0, 30)) and close(h2c((0, 0), (20, 0)), (20, 0)), "out of the face")
    # A head turned 30 deg left, eyes turned 30 deg right: back at the camera.
    t.check(close(h2c((0, -30), (0, 30)), (0, 0)) and close(h2c((-15, 0), (15, 0)), (0, 0)), "back at the camera")
    g = geometry.gaze_camera_to_head(h2c((10, -20), (15, 25)), (15, 25))
    t.check(close(g, (10, -20)), "round trip %s" % (g,))
    # The C library's labels (lib/synth: gaze_cam = head_R gaze_head).
    n = 0
    with open(os.path.join(work, "faces128", "labels.jsonl")) as f:
        for line in f:
            d = json.loads(line)
            D = math.degrees
            got = h2c((D(d["gaze_head_pitch_rad"]), D(d["gaze_head_yaw_rad"])),
                      (D(d["head_pitch_rad"]), D(d["head_yaw_rad"])), D(d["head_roll_rad"]))
            want = (D(d["gaze_cam_pitch_rad"]), D(d["gaze_cam_yaw_rad"]))
            t.check(close(got, want, 1e-5), "synth label %d: %s, C %s" % (n, got, want))
            n += 1
    t.check(n >= 3, "%d synth labels" % n)


def check_client(t, addr, face):
    with Client(addr, client_name="package-test") as c:
        fit = c.fit(face, max_iters=3)
        key = fit.subject_key
        got = [r.index for r in c.redirect([(0, 0), (10, -10), (-10, 10)], subject=key)]
        t.check(got == [0, 1, 2], "redirect indices %s" % got)
        before = c.stats().get("cancelled", 0)
        # break: the generator is closed when the loop's reference goes.
        for r in c.redirect(FAR, subject=key, fmt="raw"):
            break
        del r
        t.check(c.health().state == pb.Health.READY, "health after a redirect left by break")
        got = [r.index for r in c.redirect([(0, 0), (5, 5)], subject=key)]
        t.check(got == [0, 1], "a redirect after a break: %s" % got)
        # close() after one image.
        g = c.redirect(FAR, subject=key, fmt="raw")
        first = next(g)
        g.close()
        t.check(first.index == 0 and not c._buf, "close(): drained (%d bytes left)" % len(c._buf))
        t.check(c.fit(face, max_iters=3).cached, "fit after close()")
        # Dropped mid-stream.
        g = c.redirect(FAR, subject=key, fmt="raw")
        next(g)
        del g
        pygc.collect()
        t.check(c.health().state == pb.Health.READY, "health after a dropped redirect")
        # Never started: the next request settles it; the generator then says so.
        g = c.redirect(FAR, subject=key, fmt="raw")
        t.check(len(c.stats()) > 10, "stats while a redirect was never read")
        try:
            next(g)
            t.check(False, "an ended redirect still yields")
        except RuntimeError as e:
            t.check("cancelled" in str(e), "ended redirect: %s" % e)
        after = c.stats().get("cancelled", 0)
        print("cancelled counter %d -> %d (redirects left early: 4)" % (before, after))
        t.check(after > before, "the server saw a CANCEL take effect")
        # A server error, with its fields, through pickle.
        try:
            list(c.redirect([(99, 0)], subject=key))
            t.check(False, "pitch 99 accepted")
        except GazesplatError as e:
            r = pickle.loads(pickle.dumps(e))
            t.check(e.code == pb.ERR_INVALID_ARGUMENT and same_error(e, r) and e.request_id > 0,
                    "server error %r -> %r" % (e, r))
        t.check(c.health().state == pb.Health.READY, "connection after an error")
    return key


async def async_checks(t, addr, faces_png, key):
    async with AsyncClient(addr, client_name="package-test-aio") as c:
        t.check(c.server.version == 1 and c.server.image_size > 0, "aio hello %s" % c.server)
        fits = await asyncio.gather(*(c.fit(f, max_iters=3) for f in faces_png))
        t.check(len({f.subject_key for f in fits}) == len(faces_png), "aio: concurrent fits")
        t.check(fits[0].subject_key == key, "aio: the same key as the blocking client's fit")

        async def collect(it):
            return [r.index async for r in it]

        got, h, st = await asyncio.gather(collect(c.redirect([(0, 0), (10, 0), (0, 10)], subject=key)),
                                          c.health(), c.stats())
        t.check(got == [0, 1, 2] and h.state == pb.Health.READY and "req_redirect" in st,
                "aio: a redirect alongside health and stats: %s" % got)
        async with contextlib.aclosing(c.redirect(FAR, subject=key, fmt="raw")) as it:
            async for r in it:
                break
        t.check(not c._pending, "aio: the left redirect is finished (%s pending)" % list(c._pending))
        got = await collect(c.redirect([(0, 0)], subject=key))
        t.check(got == [0], "aio: redirect after early exit %s" % got)
        try:
            await collect(c.redirect([(99, 0)], subject=key))
            t.check(False, "aio: pitch 99 accepted")
        except GazesplatError as e:
            t.check(e.code == pb.ERR_INVALID_ARGUMENT, "aio error %r" % e)
        t.check((await c.health()).state == pb.Health.READY, "aio: connection after an error")
    try:
        await c.health()
        t.check(False, "aio: a closed client answered")
    except ConnectionError:
        pass


def labels(xs):
    return sorted((int(x["source"]), tuple(round(v, 4) for v in x["gaze_head_deg"].tolist())) for x in xs)


def check_dataset(t, addr, paths, work, photo, image_size):
    import numpy as np
    import torch
    from gazesplat.dataset import RedirectedGazeDataset

    targets = [(0, 0), (10, -20), (-15, 25), (0, -5)]
    ds = RedirectedGazeDataset(paths, gaze_targets=targets, head_targets=(0, 5), addr=addr, fit_iters=3,
                               batch=2, timeout=60, deadline_ms=60000)
    xs = list(ds)
    t.check(len(xs) == 12 == len(ds), "%d samples, len %d" % (len(xs), len(ds)))
    with Client(addr) as c:
        key0 = c.fit(open(paths[0], "rb").read(), max_iters=3)
    for s in xs:
        g = tuple(s["gaze_head_deg"].tolist())
        cam = geometry.gaze_head_to_camera(g, (0, 5))
        t.check(s["image"].shape == (3, image_size, image_size) and s["image"].dtype == torch.float32,
                "image %s" % (s["image"].shape,))
        t.check(close(s["gaze_camera_deg"].tolist(), cam, 1e-4) and close(s["head_deg"].tolist(), (0, 5), 1e-6)
                and close(s["gaze"].tolist(), [math.radians(v) for v in g], 1e-6), "labels %s" % s)
        t.check(s["source_name"] == paths[s["source"]] and len(s["subject_key"]) == 32 and
                math.isfinite(s["fit_psnr"]) and s["fit_psnr"] > 0 and math.isnan(s["quality"]) and s["epoch"] == 0,
                "metadata %s" % {k: v for k, v in s.items() if k != "image"})
        if s["source"] == 0:
            t.check(s["subject_key"] == key0.subject_key.hex() and abs(s["fit_psnr"] - key0.psnr) < 1e-3,
                    "source 0's subject key and psnr are its FIT's")
        if g == (0.0, -5.0):
            t.check(close(s["gaze_camera_deg"].tolist(), (0, 0), 1e-4), "(0, -5) with head (0, 5) looks at the camera")
    t.check(labels(xs) == sorted((i, (float(p), float(y))) for i in range(3) for p, y in targets), "every target once")
    # Batches mix sources; two workers deal the same samples.
    batches = list(torch.utils.data.DataLoader(ds, batch_size=4))
    mixed = sum(len(set(b["source"].tolist())) > 1 for b in batches)
    t.check(mixed >= 2, "batches mixing sources: %d of %d" % (mixed, len(batches)))
    two = [s for b in torch.utils.data.DataLoader(ds, batch_size=4, num_workers=2) for s in
           [{"source": b["source"][i], "gaze_head_deg": b["gaze_head_deg"][i]} for i in range(len(b["source"]))]]
    t.check(labels(two) == labels(xs), "two workers, the same samples")
    t.check(isinstance(batches[0]["source_name"], list) and batches[0]["quality"].isnan().all(),
            "metadata collates")

    # Drawn targets: a function of (seed, epoch).
    def draw(rng):
        return (rng.uniform(-20, 20), rng.uniform(-30, 30))

    def run(seed, epoch):
        d = RedirectedGazeDataset(paths[:2], gaze_targets=draw, targets_per_source=3, addr=addr, fit_iters=3,
                                  batch=3, seed=seed)
        d.set_epoch(epoch)
        return [(int(s["source"]), tuple(s["gaze_head_deg"].tolist()), s["epoch"]) for s in d]

    e0, e0b, e1 = run(5, 0), run(5, 0), run(5, 1)
    t.check(e0 == e0b and len(e0) == 6, "epoch 0 twice: the same samples in the same order")
    t.check({g for _, g, _ in e1}.isdisjoint({g for _, g, _ in e0}) and all(e == 1 for _, _, e in e1),
            "epoch 1 draws other targets")
    t.check(run(6, 0) != e0, "another seed, other targets")

    # Photos: the server finds and normalizes the face.
    ph = list(RedirectedGazeDataset([photo], gaze_targets=[(0, 0), (10, 10)], addr=addr, fit_iters=2, photo=True))
    t.check(len(ph) == 2 and ph[0]["image"].shape == (3, image_size, image_size) and ph[0]["source_name"] == photo
            and math.isfinite(ph[0]["fit_psnr"]), "photo samples %s" % [p["image"].shape for p in ph])
    # Deadline (the server's ERR_DEADLINE, through a DataLoader worker) and
    # timeout (the socket's).
    fresh = np.ascontiguousarray(np.asarray(
        __import__("PIL.Image", fromlist=["Image"]).open(paths[0]).convert("RGB"))[:, ::-1])
    dl = RedirectedGazeDataset([fresh], gaze_targets=[(0, 0)], addr=addr, fit_iters=400, deadline_ms=1)
    try:
        list(torch.utils.data.DataLoader(dl, batch_size=1, num_workers=1))
        t.check(False, "deadline 1 ms: no error")
    except GazesplatError as e:
        t.check(e.code == pb.ERR_DEADLINE, "deadline 1 ms through a worker: %r" % e)
    to = RedirectedGazeDataset([fresh[::-1].copy()], gaze_targets=[(0, 0)], addr=addr, fit_iters=400, timeout=0.001)
    try:
        list(to)
        t.check(False, "timeout 1 ms: no error")
    except OSError as e:
        t.check(isinstance(e, TimeoutError), "timeout 1 ms: %r" % e)


def main():
    daemon, cli, work, prefix, photo = sys.argv[1:6]
    t = Checks()
    check_install(t, prefix)
    check_pickle(t)
    model = tiny_model(cli, work, seed=1)
    faces_png = faces(cli, work, 128, 3)
    check_geometry(t, work)
    paths = [os.path.join(work, "faces128", "images", n)
             for n in sorted(os.listdir(os.path.join(work, "faces128", "images")))]
    d = Daemon(daemon, ["--model", model, "--set", "request_timeout_ms=100000"]).start()
    addr = "unix:" + d.sock
    try:
        with Client(addr) as c:
            h = c.wait_ready(60)
        key = check_client(t, addr, faces_png[0])
        asyncio.run(async_checks(t, addr, faces_png, key))
        check_dataset(t, addr, paths, work, photo, h.image_size)
    finally:
        rc = d.stop()
        if t.failures:
            print(d.log()[-4000:])
    t.check(rc == 0, "daemon exit %s" % rc)
    return t.status()


if __name__ == "__main__":
    t0 = time.time()
    rc = main()
    print("package checks: %.1f s" % (time.time() - t0))
    sys.exit(rc)
