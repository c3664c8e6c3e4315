"""The Python client against the real daemon (no model): HELLO, HEALTH,
STATS, errors raised as GazesplatError with their codes, BUSY retries,
CANCEL, and a frame packed by Python accepted byte for byte. Then HEALTH
LOADING and ERR_LOADING while the model is loading (the model file is a
FIFO that the test holds back), and FAILED with the reason after it.
usage: test_python_client.py GAZESPLATD"""
import errno
import math
import os
import sys
import tempfile
import threading
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.join(HERE, "..", "..", "clients", "python"))
from daemon_util import Checks, Daemon  # noqa: E402
import gazesplat_client as gc  # noqa: E402
from client_checks import expect_error  # noqa: E402


def feed_fifo(path, data):
    """Writes data to the FIFO's next reader, if one is waiting: True."""
    try:
        fd = os.open(path, os.O_WRONLY | os.O_NONBLOCK)
    except OSError as e:
        if e.errno == errno.ENXIO:  # no reader yet
            return False
        raise
    try:
        os.write(fd, data)
    except BrokenPipeError:  # the reader gave up first
        pass
    finally:
        os.close(fd)
    return True


def test_loading(t, binary):
    """The loader blocks reading a FIFO: the daemon answers meanwhile."""
    fifo = os.path.join(tempfile.mkdtemp(prefix="gsd_fifo_"), "model.safetensors")
    os.mkfifo(fifo)
    d = Daemon(binary, ["--model", fifo, "--set", "photo_input=no"]).start()
    try:
        with gc.Client("unix:" + d.sock) as c:
            h = c.health()
            t.check(h.state == gc.pb.Health.LOADING and c.server.image_size == 0,
                    "health while loading: %s" % h)
            img = b"\x89PNG\r\n\x1a\n" + b"\0" * 40
            expect_error(t, lambda: c.fit(img), gc.pb.ERR_LOADING, "fit while loading")
            expect_error(t, lambda: list(c.redirect([(0, 0)], subject=b"k" * 16)),
                         gc.pb.ERR_LOADING, "redirect while loading")
            # Release the loader (it may open the file more than once).
            end = time.time() + 10
            while time.time() < end and c.health().state == gc.pb.Health.LOADING:
                feed_fifo(fifo, b"not a model")
                time.sleep(0.02)
            h = c.health()
            t.check(h.state == gc.pb.Health.FAILED and h.detail != "", "health after a bad model: %s" % h)
            expect_error(t, lambda: c.fit(img), gc.pb.ERR_NO_MODEL, "fit after a failed load")
    finally:
        rc = d.stop()
        t.check(rc == 0, "daemon exit %s (loading test)" % rc)
        if t.failures:
            print(d.log())


def main():
    t = Checks()
    d = Daemon(os.path.abspath(sys.argv[1]),
               ["--set", "debug_requests=yes", "--set", "workers=1", "--set", "queue_depth=1",
                "--set", "photo_input=no"]).start()
    try:
        c = gc.Client("unix:" + d.sock, client_name="pytest")
        t.check(c.server.version == 1 and c.server.limits.max_targets == 64, "hello: %s" % c.server)
        h = c.health()
        t.check(h.state == gc.pb.Health.FAILED, "health state %s" % h.state)
        st = c.stats()
        t.check(st.get("req_hello", 0) >= 1 and "cache_entries" in st, "stats: %s" % st)
        expect_error(t, lambda: c.fit(b"\x89PNG\r\n\x1a\n" + b"\0" * 40, gaze_deg=(math.nan, 0)),
                     gc.pb.ERR_INVALID_ARGUMENT, "fit NaN")
        expect_error(t, lambda: c.fit(b"\xff\xd8\xff\xe0", photo=True),
                     gc.pb.ERR_PHOTO_UNSUPPORTED, "fit photo")
        expect_error(t, lambda: list(c.redirect([(0, 0)], subject=b"k" * 16)),
                     gc.pb.ERR_NO_MODEL, "redirect without a model")
        expect_error(t, lambda: list(c.redirect([(99, 0)], subject=b"k" * 16)),
                     gc.pb.ERR_INVALID_ARGUMENT, "redirect pitch 99")
        # The connection survives request errors.
        t.check(c.health().state == gc.pb.Health.FAILED, "health after errors")

        # BUSY: one worker, queue 1; a second client retries after BUSY.
        c.send(gc.FT.FRAME_SLEEP, gc.pb.Sleep(ms=400), 900)
        threading.Event().wait(0.1)  # 900 running, 901 fills the queue
        c.send(gc.FT.FRAME_SLEEP, gc.pb.Sleep(ms=10), 901)
        threading.Event().wait(0.05)
        c2 = gc.Client("unix:" + d.sock)
        try:
            c2.call(gc.FT.FRAME_SLEEP, gc.pb.Sleep(ms=1), gc.FT.FRAME_SLEEP_OK)
            t.check(False, "no BUSY with a full queue")
        except gc.Busy as b:
            t.check(b.retry_after_ms >= 10, "retry_after %d" % b.retry_after_ms)
        c3 = gc.Client("unix:" + d.sock, retry_busy=200)
        done = c3.call(gc.FT.FRAME_SLEEP, gc.pb.Sleep(ms=1), gc.FT.FRAME_SLEEP_OK)[1]
        t.check(done.seconds >= 0, "retried SLEEP answered")
        got = sorted(c.recv()[1] for _ in range(2))
        t.check(got == [900, 901], "replies %s" % got)

        # CANCEL of a running request.
        c.send(gc.FT.FRAME_SLEEP, gc.pb.Sleep(ms=5000), 950)
        threading.Event().wait(0.1)
        c.cancel(950)
        ftype, rid, _, msg = c.recv()
        t.check(ftype == gc.FT.FRAME_ERROR and rid == 950 and msg.code == gc.pb.ERR_CANCELLED,
                "cancel: %s %s %s" % (ftype, rid, msg))
        # Bytes packed here are the documented layout.
        frame = gc.pack_frame(gc.FT.FRAME_HEALTH, gc.pb.HealthRequest(), 7)
        t.check(frame == b"GAZE\x01\x00\x03\x00\x00\x00\x00\x00" + b"\0" * 16 + b"\x07\0\0\0",
                "packed HEALTH %s" % frame.hex())
        for x in (c, c2, c3):
            x.close()
    finally:
        rc = d.stop()
        t.check(rc == 0, "daemon exit %s" % rc)
        if t.failures:
            print(d.log())
    test_loading(t, os.path.abspath(sys.argv[1]))
    return t.status()


if __name__ == "__main__":
    sys.exit(main())
