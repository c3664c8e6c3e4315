"""gazesplatd's target checks with a tiny real model (issue 49): the
daemon's validation and the renderer share one table with inclusive
limits, so every target is judged before the job is queued and a target
accepted there renders. A REDIRECT with heads and gazes at exactly the
limits streams every image and DONE; one whose 6th target is a hair out
of range is refused up front (the first frame is the ERROR, no IMAGE);
a FIT with labels at the limits fits; a hair past them is refused.
usage: test_daemon_targets.py GAZESPLATD GAZESPLAT_CLI WORKDIR"""
import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.join(HERE, "..", "..", "clients", "python"))
from daemon_util import Checks, Daemon  # noqa: E402
from model_fixture import faces, tiny_model  # noqa: E402
from client_checks import expect_error, wait_ready  # noqa: E402
import gazesplat_client as gc  # noqa: E402

FAST = 3  # fit iterations


def stream(c, targets, key=None, image=None):
    """Sends one REDIRECT of targets [((gp, gy), (hp, hy) or None)] and
    reads its frames: (number of IMAGE frames, last frame type, last
    message)."""
    req = gc.pb.RedirectRequest(max_iters=FAST)
    if image is not None:
        req.image.CopyFrom(gc.pb.Image(format=gc.pb.FORMAT_PNG, data=image))
    for g, h in targets:
        tg = req.targets.add()
        tg.gaze.CopyFrom(gc.pb.Angles(pitch_deg=g[0], yaw_deg=g[1]))
        if h is not None:
            tg.head.CopyFrom(gc.pb.Angles(pitch_deg=h[0], yaw_deg=h[1]))
    rid = c.new_id()
    c.send(gc.FT.FRAME_REDIRECT, req, rid, key if key is not None else gc.ZERO_KEY)
    images = 0
    while True:
        ftype, got, _, msg = c.recv()
        if got != rid:
            continue
        if ftype != gc.FT.FRAME_IMAGE:
            return images, ftype, msg
        images += 1


def main():
    daemon, cli, work = (os.path.abspath(a) for a in sys.argv[1:4])
    os.makedirs(work, exist_ok=True)
    t = Checks()
    model = tiny_model(cli, work, seed=1)
    imgs = faces(cli, work, 128, 3)
    d = Daemon(daemon, ["--model", model, "--set", "photo_input=no"]).start()
    try:
        addr = "unix:" + d.sock
        wait_ready(t, addr)
        with gc.Client(addr) as c:
            key = c.fit(imgs[0], max_iters=FAST).subject_key
            # Five gazes at the corners of the gaze range, then a head at
            # exactly (70, -70): all six images, then DONE.
            corners = [(50, 60), (50, -60), (-50, 60), (-50, -60), (0, 60)]
            targets = [(g, None) for g in corners] + [((50, -60), (70, -70))]
            n, ftype, msg = stream(c, targets, key)
            t.check(n == 6 and ftype == gc.FT.FRAME_DONE,
                    "targets at the limits: %d images then %s %s" % (n, gc.FT.Name(ftype), msg))
            # Every head corner, every gaze corner.
            heads = [(70, 70), (70, -70), (-70, 70), (-70, -70)]
            targets = [(g, h) for g in corners[:4] for h in heads]
            n, ftype, msg = stream(c, targets, key)
            t.check(n == 16 and ftype == gc.FT.FRAME_DONE,
                    "all 16 corners: %d images then %s %s" % (n, gc.FT.Name(ftype), msg))

            # The 6th target a hair out of range: refused before any image.
            for bad, field, what in [(((50.0000001, 0), None), "gaze pitch 50.0000001", "gaze"),
                                     (((0, -60.0000001), None), "gaze yaw -60.0000001", "gaze yaw"),
                                     (((0, 0), (0, 70.0000001)), "head yaw 70.0000001", "head yaw"),
                                     (((0, 0), (-1e30, 0)), "head pitch -1e+30", "head 1e30")]:
                targets = [((0, 0), (70, 70))] * 5 + [bad]
                n, ftype, msg = stream(c, targets, key)
                t.check(n == 0 and ftype == gc.FT.FRAME_ERROR and msg.code == gc.pb.ERR_INVALID_ARGUMENT,
                        "6th target %s: %d images then %s" % (what, n, gc.FT.Name(ftype)))
                want = "target 5: %s deg outside" % field
                t.check(ftype == gc.FT.FRAME_ERROR and want in msg.message and "(inclusive)" in msg.message,
                        "6th target %s: message '%s' lacks '%s'" % (what, getattr(msg, "message", ""), want))
            # Inline: refused before the fit, no image.
            targets = [((0, 0), None)] * 5 + [((0, 0), (70.0000001, 0))]
            n, ftype, msg = stream(c, targets, image=imgs[1])
            t.check(n == 0 and ftype == gc.FT.FRAME_ERROR and msg.code == gc.pb.ERR_INVALID_ARGUMENT
                    and "target 5: head pitch" in msg.message,
                    "inline 6th target: %d images then %s %s" % (n, gc.FT.Name(ftype), msg))

            # FIT labels: the limits fit; past them refused up front.
            r = c.fit(imgs[2], gaze_deg=(50, -60), head_deg=(-70, 70), max_iters=FAST)
            t.check(abs(r.gaze.pitch_deg - 50) < 1e-6 and abs(r.head.yaw_deg - 70) < 0.01,
                    "FIT labels at the limits: %s %s" % (r.gaze, r.head))
            n, ftype, msg = stream(c, [((50, 60), (-70, -70))], r.subject_key)
            t.check(n == 1 and ftype == gc.FT.FRAME_DONE, "the subject at the limits renders")
            expect_error(t, lambda: c.fit(imgs[2], head_deg=(-70.0000001, 0), max_iters=FAST),
                         gc.pb.ERR_INVALID_ARGUMENT, "FIT head -70.0000001",
                         "FIT label: head pitch -70.0000001 deg outside [-70, 70] deg (inclusive)")
            expect_error(t, lambda: c.fit(imgs[2], gaze_deg=(0, 60.0000001), max_iters=FAST),
                         gc.pb.ERR_INVALID_ARGUMENT, "FIT gaze yaw 60.0000001", "gaze yaw 60.0000001")
            t.check(c.health().state == gc.pb.Health.READY, "connection usable")
    finally:
        rc = d.stop()
        if t.failures:
            print(d.log()[-4000:])
    t.check(rc == 0, "clean exit")
    return t.status()


if __name__ == "__main__":
    sys.exit(main())
