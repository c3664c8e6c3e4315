"""Checks the Python integration tests share, on top of gazesplat_client:
waiting for a daemon's model, and expecting a request to fail with a given
error code (and, optionally, text in its message)."""
import time

import gazesplat_client as gc


def wait_ready(t, addr, timeout=60):
    """Polls HEALTH until the state leaves LOADING; checks it is READY."""
    end = time.time() + timeout
    while time.time() < end:
        with gc.Client(addr) as c:
            h = c.health()
        if h.state != gc.pb.Health.LOADING:
            t.check(h.state == gc.pb.Health.READY, "health %s: %s" % (h.state, h.detail))
            return h
        time.sleep(0.05)
    t.check(False, "model never loaded")
    return None


def expect_error(t, fn, code, what, text=None):
    """Calls fn (draining a generator it returns) and checks that it raised
    GazesplatError with this code, and text in its message when given."""
    try:
        r = fn()
        if hasattr(r, "__next__"):
            list(r)
        t.check(False, "%s: no error" % what)
    except gc.GazesplatError as e:
        t.check(e.code == code, "%s: got %s (%s) want %s" % (what, e.name, e.message,
                                                          gc.pb.ErrorCode.Name(code)))
        if text:
            t.check(text in e.message, "%s: message '%s' lacks '%s'" % (what, e.message, text))
        return e
    return None


def refused(t, fn, code, what, text=None):
    """expect_error, printing the server's reason when it came."""
    e = expect_error(t, fn, code, what, text)
    if e:
        print("refused (%s): %s" % (what, e.message))
    return e


def start_ready(t, daemon_cls, binary, args):
    """Starts a daemon and waits for its model; returns it and its address."""
    d = daemon_cls(binary, args).start()
    addr = "unix:" + d.sock
    wait_ready(t, addr)
    return d, addr


def finish(t, d):
    """Stops daemon d (if still running), prints its log when a check
    failed, checks its exit status; returns the test's exit status."""
    rc = d.stop()
    if t.failures:
        print(d.log())
    t.check(rc in (0, None), "exit %s" % rc)
    return t.status()
