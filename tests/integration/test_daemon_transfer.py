"""gazesplatd's detail transfer (REDIRECT transfer, FIT keep_image), end to
end with a tiny real model: an inline transfer at the input's own gaze gives
the input back; transfer renders differ from plain ones and equal by key
and inline; a kept input serves by key, survives a restart as a file, is
refused with a clear ERR_UNKNOWN_SUBJECT when never kept or evicted by
input_cache_mb, and goes with a model change; a fine-tuned subject
transfers too. Also the inline REDIRECT's derived key, which covers
max_iters (two iteration counts, two subjects).
usage: test_daemon_transfer.py GAZESPLATD GAZESPLAT_CLI WORKDIR"""
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.join(HERE, "..", "..", "clients", "python"))
from daemon_util import Checks, Daemon  # noqa: E402
from model_fixture import daemon_fixture  # noqa: E402
from client_checks import finish, refused, start_ready, wait_ready  # noqa: E402
import gazesplat_client as gc  # noqa: E402

FAST = 3  # fit iterations
PHOTO = os.path.join(HERE, "..", "..", "samples", "astronaut.jpg")


def pixels(res):
    im = res.image
    a = np.frombuffer(im.data, np.uint8)
    rows = [a[y * im.stride:y * im.stride + 3 * im.width] for y in range(im.height)]
    return np.stack(rows).reshape(im.height, im.width, 3).astype(np.int32)


def render(c, targets, **kw):
    return [pixels(r) for r in c.redirect(targets, fmt="raw", **kw)]


def input_files(state):
    return sorted(f for f in os.listdir(state) if f.startswith("input-") and f.endswith(".gsfi"))


def decode(png):
    """A fixture PNG as an HxWx3 array (python3-pil, from install-deps)."""
    from PIL import Image
    import io
    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), dtype=np.int32)



def inline_and_keys(t, c, imgs, faces_rgb):
    """Inline transfers; the derived keys; kept inputs by key."""
    st0 = c.stats()
    fit = c.fit(imgs[0], max_iters=FAST)
    t.check(not fit.image_kept, "a plain FIT keeps no input")
    own = (fit.gaze.pitch_deg, fit.gaze.yaw_deg)
    targets = [own, (10, -15), (-5, 20)]
    plain = render(c, targets, subject=fit.subject_key)
    xfer = render(c, targets, image=imgs[0], max_iters=FAST, transfer=True)
    st1 = c.stats()
    t.check(st1["fits"] - st0["fits"] == 1, "the inline REDIRECT reused the FIT's subject (%d fits)"
            % (st1["fits"] - st0["fits"]))
    t.check(st1["renders_transfer"] - st0["renders_transfer"] == 3, "three transfer renders counted")
    # At the input's own gaze and pose the transfer gives the input back
    # (the angles went through degrees and back: a rounding's worth off).
    d = np.abs(xfer[0] - faces_rgb[0])
    dp = np.abs(plain[0] - faces_rgb[0])
    print("own view: transfer max %d mean %.4f; plain max %d mean %.2f"
          % (d.max(), d.mean(), dp.max(), dp.mean()))
    t.check(d.max() <= 2 and d.mean() < 0.05, "transfer at the own gaze is the input: max %d mean %.4f"
            % (d.max(), d.mean()))
    t.check(dp.mean() > 1.0, "the plain render is not the input (mean %.2f): the check above can fail"
            % dp.mean())
    for i in (1, 2):
        t.check(np.abs(xfer[i] - plain[i]).mean() > 0.5, "target %d: transfer differs from plain" % i)
    t.check(np.abs(xfer[1] - xfer[2]).mean() > 0.2, "two gazes, two transfer images")

    # By key: a FIT with keep_image of a known subject keeps it (cached).
    refused(t, lambda: render(c, targets, subject=fit.subject_key, transfer=True),
            gc.pb.ERR_UNKNOWN_SUBJECT, "transfer by key without a kept input", "keep_image")
    kept = c.fit(imgs[0], max_iters=FAST, keep_image=True)
    t.check(kept.cached and kept.image_kept and kept.subject_key == fit.subject_key,
            "keep_image on a cached subject: %s" % kept)
    bykey = render(c, targets, subject=fit.subject_key, transfer=True)
    t.check(all(np.array_equal(a, b) for a, b in zip(bykey, xfer)), "transfer by key == inline")
    again = c.fit(imgs[0], max_iters=FAST)
    t.check(again.cached and again.image_kept, "the input stays kept: %s" % again)

    # The derived key covers max_iters: another count is another subject.
    st0 = c.stats()
    render(c, [(0, 0)], image=imgs[1], max_iters=2)
    render(c, [(0, 0)], image=imgs[1], max_iters=4)
    render(c, [(0, 0)], image=imgs[1], max_iters=2)
    t.check(c.stats()["fits"] - st0["fits"] == 2, "inline keys by max_iters: %d fits for 2, 4, 2"
            % (c.stats()["fits"] - st0["fits"]))
    t.check(c.fit(imgs[1], max_iters=4).cached, "FIT with the same image and max_iters: cached")

    # A fine-tuned subject transfers too, with its own tensors.
    tuned = c.fit(imgs[2], max_iters=FAST, finetune_steps=2, keep_image=True)
    t.check(tuned.finetuned and tuned.image_kept, "fine-tuned and kept: %s" % tuned)
    tp = render(c, [(10, -15)], subject=tuned.subject_key)
    tx = render(c, [(10, -15)], subject=tuned.subject_key, transfer=True)
    t.check(np.abs(tp[0] - tx[0]).mean() > 0.5, "fine-tuned subject: transfer differs from plain")
    st = c.stats()
    t.check(st["input_entries"] == 2 and st["input_saves"] == 2, "two inputs kept and saved: %d, %d"
            % (st["input_entries"], st["input_saves"]))
    t.check(c.health().state == gc.pb.Health.READY, "still READY")
    # The plain subject's renders are compared after restarts with the same
    # sequence of targets: a sweep's second render is incremental, and the
    # incremental transfer agrees with a full one within a level on a few
    # bytes (docs/model.md), not bit for bit.
    return fit.subject_key, tuned.subject_key, (targets[:2], bykey[:2]), tx[0]


def main():
    t = Checks()
    fx = daemon_fixture(sys.argv[1:4], "state_transfer_test")
    daemon, state, model, other, imgs = fx["daemon"], fx["state"], fx["model"], fx["other"], fx["faces"]
    faces_rgb = [decode(p) for p in imgs]
    base = ["--model", model, "--state-dir", state, "--set", "photo_input=no",
            "--set", "workers=1", "--set", "max_finetune_steps=10"]
    d = Daemon(daemon, base).start()
    try:
        addr = "unix:" + d.sock
        wait_ready(t, addr)
        with gc.Client(addr) as c:
            k0, kt, x0, xt = inline_and_keys(t, c, imgs, faces_rgb)
        t.check(len(input_files(state)) == 2, "two input files: %s" % input_files(state))
        t.check(d.stop() == 0, "clean exit")

        # Restart: the kept inputs come back from their files.
        d, addr = start_ready(t, Daemon, daemon, base)
        with gc.Client(addr) as c:
            t.check(c.stats()["input_entries"] == 2, "inputs restored: %d" % c.stats()["input_entries"])
            t.check(all(np.array_equal(a, b) for a, b in
                        zip(render(c, x0[0], subject=k0, transfer=True), x0[1])),
                    "transfer by key after a restart: same bytes")
            t.check(np.array_equal(render(c, [(10, -15)], subject=kt, transfer=True)[0], xt),
                    "fine-tuned transfer after a restart: same bytes")
        t.check(d.stop() == 0, "clean exit")

        # A damaged file (truncated; then one of another size) is no kept
        # input: that subject's transfer is refused with the reason, the
        # other's still serves, and a FIT with keep_image keeps it anew.
        path = os.path.join(state, "input-%s.gsfi" % kt.hex())
        for damage in (lambda b: b[:len(b) // 2], lambda b: b[:8] + b[8:] + b"\0" * 300):
            with open(path, "rb") as f:
                blob = f.read()
            with open(path, "wb") as f:
                f.write(damage(blob))
            d, addr = start_ready(t, Daemon, daemon, base)
            with gc.Client(addr) as c:
                refused(t, lambda: render(c, [(10, -15)], subject=kt, transfer=True),
                        gc.pb.ERR_UNKNOWN_SUBJECT, "damaged input file", "no kept input")
                t.check(all(np.array_equal(a, b) for a, b in
                            zip(render(c, x0[0], subject=k0, transfer=True), x0[1])),
                        "the other subject's input still serves")
                r = c.fit(imgs[2], max_iters=FAST, finetune_steps=2, keep_image=True)
                t.check(r.cached and r.image_kept and r.subject_key == kt, "kept anew: %s" % r)
                t.check(np.array_equal(render(c, [(10, -15)], subject=kt, transfer=True)[0], xt),
                        "transfer after keeping it anew: same bytes")
            t.check(d.stop() == 0, "clean exit")

        # A 1 MiB budget holds 21 inputs of 128 px (49,160 bytes each):
        # 24 more FITs evict the oldest, whose transfer is then refused
        # with the reason, and whose files are pruned.
        d, addr = start_ready(t, Daemon, daemon, base + ["--set", "input_cache_mb=1"])
        with gc.Client(addr) as c:
            keys = [bytes([7, i]) + bytes(14) for i in range(24)]
            for k in keys:
                c.fit(imgs[1], key=k, max_iters=1, keep_image=True)
            st = c.stats()
            print("budget 1 MiB: %d inputs, %d evictions" % (st["input_entries"], st["input_evictions"]))
            t.check(st["input_entries"] == 21 and st["input_evictions"] >= 5,
                    "input_cache_mb=1: %d kept, %d evicted" % (st["input_entries"], st["input_evictions"]))
            refused(t, lambda: render(c, [(0, 0)], subject=k0, transfer=True), gc.pb.ERR_UNKNOWN_SUBJECT,
                    "evicted input", "input_cache_mb")
            t.check(len(render(c, [(0, 0)], subject=k0)) == 1, "the evicted input's subject still renders")
            t.check(len(render(c, [(0, 0)], subject=keys[-1], transfer=True)) == 1, "the newest transfers")
            t.check(len(input_files(state)) == 21, "files pruned to the kept inputs: %d"
                    % len(input_files(state)))
        t.check(d.stop() == 0, "clean exit")

        # A photo's kept input keeps what it says of its eyes (the eye
        # opening, the localized irises) with the face: a transfer by key
        # gives the inline transfer's bytes, and again after a restart,
        # from the file.
        with open(PHOTO, "rb") as f:
            photo = f.read()
        pbase = ["--model", model, "--state-dir", state, "--set", "workers=1"]
        d, addr = start_ready(t, Daemon, daemon, pbase)
        with gc.Client(addr) as c:
            kept = c.fit(photo, max_iters=FAST, keep_image=True, photo=True)
            t.check(kept.image_kept, "a photo's input kept: %s" % kept)
            own = (kept.gaze.pitch_deg, kept.gaze.yaw_deg)
            ptargets = [(own[0] + 10, own[1] - 15), (own[0] - 8, own[1] + 20)]
            inline = render(c, ptargets, image=photo, photo=True, max_iters=FAST, transfer=True)
            bykey = render(c, ptargets, subject=kept.subject_key, transfer=True)
            t.check(all(np.array_equal(a, b) for a, b in zip(bykey, inline)),
                    "a photo's transfer by key == inline (max %d)"
                    % max(int(np.abs(a - b).max()) for a, b in zip(bykey, inline)))
        t.check(d.stop() == 0, "clean exit")
        d, addr = start_ready(t, Daemon, daemon, pbase)
        with gc.Client(addr) as c:
            again = render(c, ptargets, subject=kept.subject_key, transfer=True)
            t.check(all(np.array_equal(a, b) for a, b in zip(again, inline)),
                    "a photo's transfer by key after a restart: same bytes")
        t.check(d.stop() == 0, "clean exit")

        # Another model: no input applies; the files go.
        d, addr = start_ready(t, Daemon, daemon,
                              ["--model", other, "--state-dir", state, "--set", "photo_input=no"])
        with gc.Client(addr) as c:
            t.check(c.stats()["input_entries"] == 0, "no inputs for another model")
        t.check(input_files(state) == [], "input files removed for another model: %s" % input_files(state))
    finally:
        status = finish(t, d)
    return status


if __name__ == "__main__":
    sys.exit(main())
