"""gazesplatd end to end with a tiny real model (trained at test time):
FIT (derived and chosen keys, cache hits, known labels), REDIRECT by key
and inline (PNG, JPEG, raw), photo input (detection, normalization,
paste-back, no face), CANCEL midway, image errors (wrong size, corrupt,
decompression bomb), persistence across a restart, SIGHUP model reload, a
different model dropping the old subjects.
usage: test_daemon_model.py GAZESPLATD GAZESPLAT_CLI WORKDIR"""
import os
import struct
import sys
import time
import zlib

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.join(HERE, "..", "..", "clients", "python"))
from daemon_util import Checks, Daemon  # noqa: E402
from model_fixture import faces, tiny_model  # noqa: E402
from client_checks import expect_error, wait_ready  # noqa: E402
import gazesplat_client as gc  # noqa: E402

FAST = 3  # fit iterations: enough to exercise the path, fast on 2 cores


def png_chunk(kind, data):
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def bomb_png(w, h):
    """A PNG whose header claims w x h: refused before any pixel is decoded."""
    ihdr = struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + png_chunk(b"IHDR", ihdr) +
            png_chunk(b"IDAT", zlib.compress(b"\0" * 64)) + png_chunk(b"IEND", b""))


def test_fit_and_redirect(t, addr, imgs, size):
    with gc.Client(addr) as c:
        t.check(c.server.image_size == size, "image_size %d" % c.server.image_size)
        r1 = c.fit(imgs[0], max_iters=FAST)
        t.check(len(r1.subject_key) == 16 and not r1.cached and r1.iters == FAST,
                "first fit: %s" % r1)
        t.check(r1.psnr > 5 and 0 < r1.ssim <= 1, "fit quality psnr %.2f ssim %.3f" % (r1.psnr, r1.ssim))
        r2 = c.fit(imgs[0], max_iters=FAST)
        t.check(r2.cached and r2.subject_key == r1.subject_key, "refit is a cache hit: %s" % r2)
        key = bytes(range(100, 116))
        r3 = c.fit(imgs[1], key=key, gaze_deg=(5, -5), head_deg=(0, 10), max_iters=FAST)
        t.check(r3.subject_key == key, "chosen key kept")
        t.check(abs(r3.gaze.pitch_deg - 5) < 1e-6 and abs(r3.gaze.yaw_deg + 5) < 1e-6,
                "known gaze kept: %s" % r3.gaze)
        t.check(abs(r3.head.yaw_deg - 10) < 0.01, "known head kept: %s" % r3.head)

        # The worker renders each fitted subject once the FIT reply is out
        # and keeps those renders: a sweep of a fitted subject is
        # incremental from the first target on. (This REDIRECT also waits
        # for that render of the last FIT.)
        list(c.redirect([(1, 1)], subject=key))
        st0 = c.stats()
        targets = [(0, 0), (15, -20), (-10, 30)]
        res = list(c.redirect(targets, subject=r1.subject_key))
        st1 = c.stats()
        inc = st1["renders_incremental"] - st0["renders_incremental"]
        full = st1["renders_full"] - st0["renders_full"]
        t.check(inc == 3 and full == 0, "sweep renders: %d incremental, %d full" % (inc, full))
        t.check(st0["renders_full"] == 2 and st0["renders_incremental"] == 2,
                "renders after 3 FITs and a REDIRECT: %d full, %d incremental"
                % (st0["renders_full"], st0["renders_incremental"]))
        t.check([r.index for r in res] == [0, 1, 2], "indices %s" % [r.index for r in res])
        for r in res:
            d = r.image.data
            t.check(r.image.format == gc.pb.FORMAT_PNG and d[:8] == b"\x89PNG\r\n\x1a\n" and
                    struct.unpack(">II", d[16:24]) == (size, size), "PNG %dx%d" % struct.unpack(">II", d[16:24]))
        t.check(res[1].target.gaze.pitch_deg == 15 and res[1].target.gaze.yaw_deg == -20, "target echoed")
        t.check(res[0].image.data != res[1].image.data, "different gazes give different images")
        raw = list(c.redirect([(5, 5)], subject=r1.subject_key, fmt="raw", head_deg=[(0, 15)]))
        arr = gc.image_array(raw[0])
        t.check(arr.shape == (size, size, 3) and arr.std() > 1, "raw %s std %.2f" % (arr.shape, arr.std()))
        jpg = list(c.redirect([(0, 0)], subject=key, fmt="jpeg", jpeg_quality=80))
        t.check(jpg[0].image.data[:3] == b"\xff\xd8\xff", "JPEG output")
        inline = list(c.redirect([(0, 10), (0, -10)], image=imgs[2], max_iters=FAST))
        t.check(len(inline) == 2, "inline source: %d images" % len(inline))
        # The same PNG bytes twice: identical (deterministic renders).
        again = list(c.redirect([(15, -20)], subject=r1.subject_key))
        t.check(again[0].image.data == res[1].image.data, "renders are deterministic")

        expect_error(t, lambda: c.redirect([(0, 0)], subject=b"\x01" * 16), gc.pb.ERR_UNKNOWN_SUBJECT,
                     "unknown subject")
        small = faces_small[0]
        expect_error(t, lambda: c.fit(small), gc.pb.ERR_BAD_IMAGE, "64 px face for a 128 px model")
        expect_error(t, lambda: c.fit(imgs[0][:200]), gc.pb.ERR_BAD_IMAGE, "truncated PNG")
        expect_error(t, lambda: c.fit(bomb_png(100000, 100000)), gc.pb.ERR_IMAGE_TOO_LARGE,
                     "PNG bomb 100000^2")
        expect_error(t, lambda: c.fit(bomb_png(4000, 4000)), gc.pb.ERR_IMAGE_TOO_LARGE,
                     "PNG over max_image_mpix")
        t.check(c.health().state == gc.pb.Health.READY, "still READY")
        return r1.subject_key, key


def test_cancel(t, addr, key):
    with gc.Client(addr) as c:
        rid = c.new_id()
        req = gc.pb.RedirectRequest()
        for i in range(40):
            req.targets.add().gaze.CopyFrom(gc.pb.Angles(pitch_deg=i % 20, yaw_deg=0))
        c.send(gc.FT.FRAME_REDIRECT, req, rid, key)
        ftype, got, _, _ = c.recv()
        t.check(ftype == gc.FT.FRAME_IMAGE and got == rid, "first image before cancel")
        c.cancel(rid)
        images = 1
        while True:
            ftype, got, _, msg = c.recv()
            if ftype != gc.FT.FRAME_IMAGE:
                break
            images += 1
        t.check(ftype == gc.FT.FRAME_ERROR and msg.code == gc.pb.ERR_CANCELLED and images < 40,
                "cancel midway: %d images then %s" % (images, gc.FT.Name(ftype)))
        t.check(c.health().state == gc.pb.Health.READY, "connection usable after cancel")


faces_small = []
ASTRONAUT = "/usr/lib/python3/dist-packages/skimage/data/astronaut.png"


def test_photo(t, addr, size):
    """A real photo (python3-skimage's astronaut, 512 x 512, one face)."""
    import numpy as np
    with gc.Client(addr) as c:
        t.check(c.server.photo_input and c.health().photo_input, "photo input advertised")
        if not os.path.exists(ASTRONAUT):
            print("SKIP photo checks: %s missing (python3-skimage)" % ASTRONAUT)
            return
        photo = open(ASTRONAUT, "rb").read()
        r = c.fit(photo, photo=True, max_iters=FAST)
        t.check(not r.cached and len(r.subject_key) == 16, "photo fit: %s" % r)
        # The landmarks' head pose is kept: a near-frontal astronaut.
        t.check(abs(r.head.yaw_deg) < 30 and abs(r.head.pitch_deg) < 40, "photo head %s" % r.head)
        out = list(c.redirect([(0, 0)], subject=r.subject_key, fmt="raw"))
        t.check(gc.image_array(out[0]).shape == (size, size, 3), "normalized render of a photo subject")
        req = gc.pb.RedirectRequest(image=gc.pb.Image(format=gc.pb.FORMAT_PNG, data=photo, kind=gc.pb.KIND_PHOTO),
                                    output_mode=gc.pb.OUTPUT_PASTE_BACK, output_format=gc.pb.FORMAT_RAW_RGB8,
                                    max_iters=FAST)
        req.targets.add().gaze.CopyFrom(gc.pb.Angles(pitch_deg=10, yaw_deg=-15))
        tg = req.targets.add()
        tg.gaze.CopyFrom(gc.pb.Angles())
        tg.head.CopyFrom(gc.pb.Angles(yaw_deg=15))
        rid = c.new_id()
        c.send(gc.FT.FRAME_REDIRECT, req, rid)
        res = list(c._images(rid))
        arrs = [gc.image_array(x) for x in res]
        t.check(len(arrs) == 2 and all(a.shape == (512, 512, 3) for a in arrs), "paste-back size")
        if len(arrs) == 2:
            # Eyes only for a gaze target, the whole face when the head
            # turns; the photo's corners are untouched either way.
            t.check(int(np.count_nonzero(arrs[0] != arrs[1])) > 0, "paste-backs differ")
            t.check((arrs[0][:40, :40] == arrs[1][:40, :40]).all(), "corners untouched")
        flat = np.full((200, 200, 3), 128, np.uint8)
        expect_error(t, lambda: c.fit(flat, photo=True), gc.pb.ERR_NO_FACE, "photo without a face")
        expect_error(t, lambda: _paste_normalized(c), gc.pb.ERR_INVALID_ARGUMENT,
                     "paste-back of a normalized face")


imgs_for_photo = []


def _paste_normalized(c):
    req = gc.pb.RedirectRequest(image=gc.pb.Image(format=gc.pb.FORMAT_PNG, data=imgs_for_photo[0]),
                                output_mode=gc.pb.OUTPUT_PASTE_BACK)
    req.targets.add().gaze.CopyFrom(gc.pb.Angles())
    rid = c.new_id()
    c.send(gc.FT.FRAME_REDIRECT, req, rid)
    return c._images(rid)


def main():
    daemon, cli, work = (os.path.abspath(a) for a in sys.argv[1:4])
    os.makedirs(work, exist_ok=True)
    t = Checks()
    model = tiny_model(cli, work, seed=1)
    other = tiny_model(cli, work, seed=2)
    imgs = faces(cli, work, 128, 3)
    faces_small.extend(faces(cli, work, 64, 1))
    state = os.path.join(work, "state_model_test")
    os.makedirs(state, exist_ok=True)
    for f in os.listdir(state):
        os.unlink(os.path.join(state, f))
    args = ["--model", model, "--state-dir", state, "--set", "max_image_mpix=8", "--log-level", "debug"]
    d = Daemon(daemon, args).start()
    try:
        addr = "unix:" + d.sock
        h = wait_ready(t, addr)
        size = h.image_size if h else 0
        key1, key2 = test_fit_and_redirect(t, addr, imgs, size)
        test_cancel(t, addr, key1)
        imgs_for_photo.extend(imgs)
        test_photo(t, addr, size)
        # SIGHUP reloads the same model: subjects stay.
        d.proc.send_signal(1)
        time.sleep(1.0)
        with gc.Client(addr) as c:
            st = c.stats()
            t.check(st["model_loads"] == 2 and st["reloads"] == 1, "after SIGHUP: loads %d reloads %d"
                    % (st["model_loads"], st["reloads"]))
            t.check(len(list(c.redirect([(0, 0)], subject=key2))) == 1, "subject kept across reload")
        t.check(d.stop() == 0, "clean exit")
        # Restart: the subjects come back from the state directory (no
        # photos from here on: skip loading the 100 MB landmark model).
        args += ["--set", "photo_input=no"]
        d = Daemon(daemon, args).start()
        addr = "unix:" + d.sock
        wait_ready(t, addr)
        with gc.Client(addr) as c:
            t.check(c.stats()["cache_entries"] >= 3, "subjects reloaded: %d" % c.stats()["cache_entries"])
            t.check(len(list(c.redirect([(0, 0)], subject=key1))) == 1, "subject 1 after restart")
            t.check(c.fit(imgs[1], key=key2).cached, "subject 2 after restart")
        t.check(d.stop() == 0, "clean exit")
        # Another model: the old subjects do not apply to it.
        d = Daemon(daemon, ["--model", other, "--state-dir", state, "--set", "photo_input=no"]).start()
        addr = "unix:" + d.sock
        wait_ready(t, addr)
        with gc.Client(addr) as c:
            expect_error(t, lambda: c.redirect([(0, 0)], subject=key1), gc.pb.ERR_UNKNOWN_SUBJECT,
                         "subject of another model")
    finally:
        rc = d.stop()
        if t.failures:
            print(d.log())
    t.check(rc in (0, None), "exit %s" % rc)
    return t.status()


if __name__ == "__main__":
    sys.exit(main())
