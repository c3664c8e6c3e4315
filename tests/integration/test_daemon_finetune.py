"""gazesplatd serving fine-tuned subjects, end to end with a tiny real
model: FIT with finetune_steps (result fields, a key of its own, cache
hits), REDIRECT alternating between fine-tuned and plain subjects on one
worker (same bytes every time; two subjects held without switching,
incrementally; a third switches the least recently used), an inline REDIRECT that fine-tunes, bad
requests, the blocks' files across restarts, eviction by tuned_cache_mb
(a clear ERR_UNKNOWN_SUBJECT, the files pruned) and a model change
dropping them all.
usage: test_daemon_finetune.py GAZESPLATD GAZESPLAT_CLI WORKDIR"""
import os
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.join(HERE, "..", "..", "clients", "python"))
from daemon_util import Checks, Daemon  # noqa: E402
from model_fixture import faces, tiny_model  # noqa: E402
from client_checks import refused, start_ready, wait_ready  # noqa: E402
import gazesplat_client as gc  # noqa: E402

FAST = 3   # fit iterations
STEPS = 4  # fine-tuning steps



def raw(c, key, gaze=(10, -15)):
    return list(c.redirect([gaze], subject=key, fmt="raw"))[0].image.data


def tuned_files(state):
    return sorted(f for f in os.listdir(state) if f.startswith("tuned-") and f.endswith(".gsft"))


def serve(t, addr, imgs, state):
    """FITs, REDIRECT switches and bad requests; returns the keys and the
    tuned renders to compare after a restart."""
    with gc.Client(addr) as c:
        plain = c.fit(imgs[0], max_iters=FAST)
        t.check(not plain.finetuned and plain.finetune_steps == 0, "plain fit: %s" % plain)
        tuned0 = c.fit(imgs[0], max_iters=FAST, finetune_steps=STEPS)
        t.check(tuned0.finetuned and tuned0.finetune_steps == STEPS and not tuned0.cached,
                "fine-tuned fit: %s" % tuned0)
        t.check(tuned0.subject_key != plain.subject_key, "a fine-tuned subject has a key of its own")
        t.check(tuned0.finetune_psnr > tuned0.psnr, "fine-tuning improved the input's PSNR: %.2f -> %.2f"
                % (tuned0.psnr, tuned0.finetune_psnr))
        key1 = bytes(range(40, 56))
        tuned1 = c.fit(imgs[1], key=key1, max_iters=FAST, finetune_steps=3, finetune_parts="face,eye")
        t.check(tuned1.finetuned and tuned1.subject_key == key1, "face,eye fine-tune: %s" % tuned1)
        again = c.fit(imgs[0], max_iters=FAST, finetune_steps=STEPS)
        t.check(again.cached and again.finetuned and again.subject_key == tuned0.subject_key,
                "the same fine-tuned FIT is a cache hit: %s" % again)
        st = c.stats()
        t.check(st["finetunes"] == 2 and st["tuned_entries"] == 2, "stats: finetunes %d, tuned_entries %d"
                % (st["finetunes"], st["tuned_entries"]))
        t.check(len(tuned_files(state)) == 2, "block files: %s" % tuned_files(state))

        # The worker holds both fine-tuned subjects (tuned_subjects = 2):
        # alternating between them switches nothing and renders
        # incrementally; every render of a subject is the same bytes,
        # whatever was rendered before.
        k0, kp = tuned0.subject_key, plain.subject_key
        first = {k: raw(c, k) for k in (k0, kp, key1)}
        t.check(first[k0] != first[kp], "the fine-tuned render differs from the plain one")
        st0 = c.stats()
        for k in (k0, key1, kp, k0, kp, key1, k0):
            t.check(raw(c, k) == first[k], "render of %s after switching" % k.hex()[:8])
        st1 = c.stats()
        t.check(st1["tuned_swaps"] == st0["tuned_swaps"], "two slots, two subjects: %d switches"
                % (st1["tuned_swaps"] - st0["tuned_swaps"]))
        t.check(st1["renders_full"] == st0["renders_full"] and
                st1["renders_incremental"] - st0["renders_incremental"] == 7,
                "alternating subjects render incrementally: %d full, %d incremental"
                % (st1["renders_full"] - st0["renders_full"],
                   st1["renders_incremental"] - st0["renders_incremental"]))
        sweep = list(c.redirect([(0, 0), (15, -20), (-10, 30)], subject=k0, fmt="raw"))
        t.check(len({r.image.data for r in sweep}) == 3, "a fine-tuned sweep: three different images")

        # Inline: fit, fine-tune and render in one request; the subject is
        # kept under the key a FIT of the same image and settings gets.
        inline = list(c.redirect([(0, 10)], image=imgs[2], max_iters=FAST, finetune_steps=2,
                                 fmt="raw"))
        t.check(len(inline) == 1, "inline fine-tuned REDIRECT")
        r = c.fit(imgs[2], max_iters=FAST, finetune_steps=2)
        t.check(r.cached and r.finetuned, "inline subject cached as fine-tuned: %s" % r)
        t.check(raw(c, r.subject_key, (0, 10)) == inline[0].image.data, "inline render == render by key")
        # Three fine-tuned subjects, two slots: the least recently used slot
        # switches, and the renders stay the same bytes.
        st0 = c.stats()
        for k in (k0, key1, r.subject_key, k0, key1):
            if k in first:
                t.check(raw(c, k) == first[k], "render of %s with three subjects" % k.hex()[:8])
            else:
                raw(c, k)
        t.check(c.stats()["tuned_swaps"] - st0["tuned_swaps"] >= 3, "switches counted: %d"
                % (c.stats()["tuned_swaps"] - st0["tuned_swaps"]))

        # Bad requests: answered with a reason, the server unharmed.
        refused(t, lambda: c.fit(imgs[0], finetune_steps=51), gc.pb.ERR_INVALID_ARGUMENT,
                     "steps over max_finetune_steps", "max_finetune_steps")
        refused(t, lambda: c.fit(imgs[0], finetune_steps=2, finetune_parts="nose"),
                     gc.pb.ERR_INVALID_ARGUMENT, "unknown part", "nose")
        refused(t, lambda: c.fit(imgs[0], finetune_steps=2, finetune_parts="face,"),
                     gc.pb.ERR_INVALID_ARGUMENT, "empty part")
        refused(t, lambda: c.fit(imgs[0], finetune_parts="face"), gc.pb.ERR_INVALID_ARGUMENT,
                     "parts without steps")
        refused(t, lambda: c.redirect([(0, 0)], subject=k0, finetune_steps=2),
                     gc.pb.ERR_INVALID_ARGUMENT, "fine-tuning a subject by key")
        t.check(c.health().state == gc.pb.Health.READY, "still READY")
        return k0, kp, key1, r.subject_key, first


def main():
    daemon, cli, work = (os.path.abspath(a) for a in sys.argv[1:4])
    os.makedirs(work, exist_ok=True)
    t = Checks()
    model = tiny_model(cli, work, seed=1)
    other = tiny_model(cli, work, seed=2)
    imgs = faces(cli, work, 128, 3)
    state = os.path.join(work, "state_finetune_test")
    os.makedirs(state, exist_ok=True)
    for f in os.listdir(state):
        os.unlink(os.path.join(state, f))
    base = ["--model", model, "--state-dir", state, "--set", "photo_input=no",
            "--set", "max_finetune_steps=50", "--set", "workers=1", "--set", "tuned_subjects=2"]
    d = Daemon(daemon, base).start()
    rc = None
    try:
        addr = "unix:" + d.sock
        wait_ready(t, addr)
        k0, kp, k1, k2, first = serve(t, addr, imgs, state)
        t.check(len(tuned_files(state)) == 3, "three block files: %s" % tuned_files(state))
        t.check(d.stop() == 0, "clean exit")

        # Restart: the blocks come back from their files, same renders.
        d, addr = start_ready(t, Daemon, daemon, base)
        with gc.Client(addr) as c:
            t.check(c.stats()["tuned_entries"] == 3, "blocks restored: %d" % c.stats()["tuned_entries"])
            for k in (k0, kp, k1):
                t.check(raw(c, k) == first[k], "render of %s after a restart" % k.hex()[:8])
        t.check(d.stop() == 0, "clean exit")

        # A budget for one block (the tiny model's face block is 0.54 MB):
        # the newest file is kept, the others go, and their subjects say
        # so; plain subjects are unaffected.
        d, addr = start_ready(t, Daemon, daemon, base + ["--set", "tuned_cache_mb=1"])
        with gc.Client(addr) as c:
            t.check(c.stats()["tuned_entries"] == 1, "one block within 1 MiB: %d"
                    % c.stats()["tuned_entries"])
            t.check(len(tuned_files(state)) == 1, "files pruned to the kept block: %s" % tuned_files(state))
            t.check(raw(c, k2, (0, 10)) is not None, "the newest fine-tuned subject renders")
            refused(t, lambda: raw(c, k0), gc.pb.ERR_UNKNOWN_SUBJECT, "evicted block", "fit it again")
            t.check(raw(c, kp) == first[kp], "plain subject unaffected")
            # A new fine-tune evicts the kept one in turn.
            r = c.fit(imgs[1], max_iters=FAST, finetune_steps=2)
            t.check(r.finetuned, "fine-tune within the budget")
            refused(t, lambda: raw(c, k2, (0, 10)), gc.pb.ERR_UNKNOWN_SUBJECT, "evicted by a new block")
            t.check(len(tuned_files(state)) == 1, "one block file: %s" % tuned_files(state))
            t.check(c.stats()["tuned_evictions"] >= 1, "evictions counted")
            # Fitting an evicted subject again runs the fit and the
            # fine-tune anew (not a cache hit) and gives the same renders.
            r = c.fit(imgs[0], max_iters=FAST, finetune_steps=STEPS)
            t.check(r.subject_key == k0 and not r.cached and r.finetuned and r.finetune_steps == STEPS,
                    "an evicted subject is fitted again: %s" % r)
            t.check(raw(c, k0) == first[k0], "the refitted subject renders the same bytes")
        t.check(d.stop() == 0, "clean exit")

        # Another model: no block applies; the files go.
        d, addr = start_ready(t, Daemon, daemon,
                              ["--model", other, "--state-dir", state, "--set", "photo_input=no"])
        with gc.Client(addr) as c:
            refused(t, lambda: raw(c, k1), gc.pb.ERR_UNKNOWN_SUBJECT, "fine-tuned subject of another model")
            t.check(c.stats()["tuned_entries"] == 0, "no blocks for another model")
        t.check(tuned_files(state) == [], "block files removed for another model: %s" % tuned_files(state))
        t.check(d.stop() == 0, "clean exit")

        # finetune_outline_px: a subject of its own (the library test checks
        # what it changes); 0..8, with finetune_steps only. This server
        # fine-tunes at 0.002 when a request names no rate (its file says).
        conf = os.path.join(work, "finetune_lr.conf")
        with open(conf, "w") as f:
            f.write("finetune_lr = 0.002\n")
        d, addr = start_ready(t, Daemon, daemon, ["-c", conf, "--model", other, "--set", "photo_input=no"])
        with gc.Client(addr) as c:
            a = c.fit(imgs[0], max_iters=FAST, finetune_steps=2)
            t.check(a.finetuned and a.finetune_lr == 0.002, "the server's rate ran: %s" % a)
            # finetune_lr: the server's rate named is the same subject;
            # another rate tunes another one, rendered by key or inline alike.
            same = c.fit(imgs[0], max_iters=FAST, finetune_steps=2, finetune_lr=0.002)
            t.check(same.cached and same.subject_key == a.subject_key and same.finetune_lr == 0,
                    "the server's rate by name: the same subject, a cache hit: %s" % same)
            slow = c.fit(imgs[0], max_iters=FAST, finetune_steps=2, finetune_lr=0.0005)
            t.check(slow.finetuned and not slow.cached and slow.finetune_lr == 0.0005 and
                    slow.subject_key != a.subject_key, "rate 0.0005: a subject of its own: %s" % slow)
            t.check(raw(c, slow.subject_key, (0, 10)) != raw(c, a.subject_key, (0, 10)),
                    "rate 0.0005 renders other bytes")
            inl = list(c.redirect([(0, 10)], image=imgs[0], max_iters=FAST, finetune_steps=2,
                                  finetune_lr=0.0005, fmt="raw"))
            t.check(len(inl) == 1 and inl[0].image.data == raw(c, slow.subject_key, (0, 10)),
                    "inline REDIRECT at rate 0.0005 is that subject")
            for bad in (1.5, -0.001, float("nan"), float("inf")):
                refused(t, lambda: c.fit(imgs[0], finetune_steps=2, finetune_lr=bad),
                        gc.pb.ERR_INVALID_ARGUMENT, "rate %r" % bad, "out of (0, 1]")
            refused(t, lambda: c.fit(imgs[0], finetune_lr=0.01), gc.pb.ERR_INVALID_ARGUMENT,
                    "rate without steps", "finetune_lr without finetune_steps")
            refused(t, lambda: c.redirect([(0, 0)], subject=a.subject_key, finetune_lr=0.01),
                    gc.pb.ERR_INVALID_ARGUMENT, "rate for a subject by key")
            # SIGHUP re-reads the file: the next fine-tune runs at its new rate.
            with open(conf, "w") as f:
                f.write("finetune_lr = 0.003\n")
            reloads = c.stats()["reloads"]
            d.proc.send_signal(1)
            for _ in range(100):
                if c.stats()["reloads"] > reloads:
                    break
                time.sleep(0.05)
            hup = c.fit(imgs[1], max_iters=FAST, finetune_steps=2)
            t.check(hup.finetuned and hup.finetune_lr == 0.003, "after SIGHUP the file's new rate: %s" % hup)
            b = c.fit(imgs[0], max_iters=FAST, finetune_steps=2, finetune_outline_px=2)
            t.check(a.finetuned and b.finetuned and not b.cached and a.subject_key != b.subject_key,
                    "outline 2: fine-tuned, a key of its own: %s / %s" % (a, b))
            t.check(raw(c, a.subject_key, (0, 10)) != raw(c, b.subject_key, (0, 10)),
                    "outline 2 renders other bytes")
            refused(t, lambda: c.fit(imgs[0], finetune_steps=2, finetune_outline_px=9),
                    gc.pb.ERR_INVALID_ARGUMENT, "outline over 8", "over 8")
            refused(t, lambda: c.fit(imgs[0], finetune_outline_px=1), gc.pb.ERR_INVALID_ARGUMENT,
                    "outline without steps", "finetune_outline_px without finetune_steps")
            refused(t, lambda: c.redirect([(0, 0)], subject=a.subject_key, finetune_outline_px=1),
                    gc.pb.ERR_INVALID_ARGUMENT, "outline for a subject by key")
            # finetune_mirror=False (finetune_no_mirror): the input alone, a key of its own.
            n = c.fit(imgs[0], max_iters=FAST, finetune_steps=2, finetune_mirror=False)
            t.check(n.finetuned and n.subject_key not in (a.subject_key, b.subject_key),
                    "no mirror: a key of its own: %s" % n)
            t.check(raw(c, n.subject_key, (0, 10)) != raw(c, a.subject_key, (0, 10)),
                    "no mirror renders other bytes")
            refused(t, lambda: c.fit(imgs[0], finetune_mirror=False), gc.pb.ERR_INVALID_ARGUMENT,
                    "no mirror without steps", "finetune_no_mirror without finetune_steps")
            t.check(c.health().state == gc.pb.Health.READY, "still READY")
    finally:
        rc = d.stop()
        if t.failures:
            print(d.log())
    t.check(rc in (0, None), "exit %s" % rc)
    return t.status()


if __name__ == "__main__":
    sys.exit(main())
