"""gazesplatd's observability without a model (SLEEP requests): the
Prometheus endpoint on TCP and on a Unix socket, scraped over HTTP and
parsed (every STATS figure, per-type latency histograms that add up),
404/405 for other requests, and one info log line per compute request,
refusals included.
usage: test_daemon_metrics.py GAZESPLATD"""
import os
import re
import socket
import sys
import time
import urllib.error
import urllib.request

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.join(HERE, "..", "..", "clients", "python"))
from daemon_util import Checks, Daemon, free_port, unix_request  # noqa: E402
import gazesplat_client as gc  # noqa: E402

FT = gc.pb.FrameType
LINE = re.compile(r'^([a-zA-Z_:][a-zA-Z0-9_:]*)(\{[^}]*\})? (-?[0-9.e+]+|\+Inf)$')


def parse(t, body):
    """{(name, labels): value} from a text exposition; checks its grammar."""
    series, typed = {}, set()
    for ln in body.splitlines():
        if ln.startswith("# TYPE "):
            name, kind = ln.split()[2:4]
            t.check(kind in ("counter", "gauge", "histogram"), "type %s" % ln)
            typed.add(name)
            continue
        if ln.startswith("#") or not ln:
            continue
        m = LINE.match(ln)
        if not t.check(m is not None, "exposition line %r" % ln):
            continue
        base = re.sub(r"_(bucket|sum|count)$", "", m.group(1))
        t.check(m.group(1) in typed or base in typed, "%s has a TYPE line" % m.group(1))
        series[(m.group(1), m.group(2) or "")] = float(m.group(3))
    return series


def sleep(c, ms, deadline=0):
    rid = c.new_id()
    c.send(FT.FRAME_SLEEP, gc.pb.Sleep(ms=ms, deadline_ms=deadline), rid)
    while True:
        ftype, got, _k, msg = c.recv()
        if got == rid:
            return ftype, msg


def http(addr, path, method="GET"):
    req = urllib.request.Request("http://%s%s" % (addr, path), method=method)
    try:
        with urllib.request.urlopen(req, timeout=10) as r:
            return r.status, r.headers.get("Content-Type"), r.read().decode()
    except urllib.error.HTTPError as e:
        return e.code, e.headers.get("Content-Type"), e.read().decode()


def main():
    t = Checks()
    daemon = os.path.abspath(sys.argv[1])
    addr = "127.0.0.1:%d" % free_port()
    d = Daemon(daemon, ["--set", "debug_requests=yes", "--set", "metrics=" + addr,
                        "--log-level", "info"]).start()
    try:
        with gc.Client(d.sock) as c:
            for _ in range(3):
                ftype, _m = sleep(c, 60)
                t.check(ftype == FT.FRAME_SLEEP_OK, "sleep ok")
            ftype, m = sleep(c, 200, deadline=50)
            t.check(ftype == FT.FRAME_ERROR and m.code == gc.pb.ERR_DEADLINE, "deadline: %s" % m)
            ftype, m = sleep(c, 70000)
            t.check(ftype == FT.FRAME_ERROR and m.code == gc.pb.ERR_INVALID_ARGUMENT, "refused: %s" % m)
            c.health()
            # The SLEEP cut by its deadline was answered when the deadline
            # passed; its worker lets go at its next check. Wait for that,
            # so that STATS and the scrape see the same gauges.
            end = time.time() + 10
            stats = c.stats()
            while stats.get("jobs_running", 0) and time.time() < end:
                time.sleep(0.02)
                stats = c.stats()
        status, ctype, body = http(addr, "/metrics")
        t.check(status == 200 and ctype.startswith("text/plain; version=0.0.4"), "200 %s" % ctype)
        s = parse(t, body)
        t.check(s.get(("gazesplatd_req_sleep_total", "")) == 5, "req_sleep_total %s"
                % s.get(("gazesplatd_req_sleep_total", "")))
        t.check(s.get(("gazesplatd_deadline_exceeded_total", "")) == 1, "deadline_exceeded_total")
        for name, v in stats.items():
            if name in ("uptime_ms", "frames_in", "frames_out", "bytes_in", "bytes_out", "req_stats",
                        "conn_accepted", "conn_closed", "connections_open"):
                continue  # moved by the scrape's own connection or by time
            key = ("gazesplatd_%s_total" % name, "") if ("gazesplatd_%s_total" % name, "") in s \
                else ("gazesplatd_%s" % name, "")
            t.check(key in s and s[key] == v, "%s: STATS %d, metrics %s" % (name, v, s.get(key)))
        # The SLEEP histogram: 4 that ran (3 ok, one cut by its deadline);
        # the refused one never queued. Buckets cumulative, +Inf = count.
        lab = lambda le: '{type="sleep",le="%s"}' % le  # noqa: E731
        buckets = sorted((float(k[1].split('le="')[1].rstrip('"}')), v) for k, v in s.items()
                         if k[0] == "gazesplatd_request_duration_seconds_bucket" and 'type="sleep"' in k[1]
                         and "+Inf" not in k[1])
        t.check(len(buckets) == 14 and all(a[1] <= b[1] for a, b in zip(buckets, buckets[1:])),
                "cumulative buckets %s" % buckets)
        count = s.get(("gazesplatd_request_duration_seconds_count", '{type="sleep"}'))
        t.check(count == 4 and s.get(("gazesplatd_request_duration_seconds_bucket", lab("+Inf"))) == 4,
                "sleep count %s" % count)
        total = s.get(("gazesplatd_request_duration_seconds_sum", '{type="sleep"}'), 0)
        t.check(0.2 <= total < 5, "sleep seconds %.3f" % total)
        t.check(s.get(("gazesplatd_request_duration_seconds_bucket", lab(0.025))) == 0 and
                s.get(("gazesplatd_request_duration_seconds_bucket", lab(0.25))) == 4,
                "four requests of 50-60 ms between the 25 and 250 ms bounds")
        t.check(any(k[0] == "gazesplatd_info" and "version=" in k[1] for k in s), "info series")
        status, _c, _b = http(addr, "/other")
        t.check(status == 404, "other path: %d" % status)
        status, _c, _b = http(addr, "/metrics", method="POST")
        t.check(status == 405, "POST: %d" % status)
        # A request head that never ends is closed, and the daemon serves on.
        host, port = addr.split(":")
        raw = socket.create_connection((host, int(port)))
        raw.sendall(b"GET /metrics HTTP/1.1\r\nX: " + b"a" * 5000)
        raw.settimeout(5)
        try:
            closed = raw.recv(100) == b""
        except ConnectionResetError:
            closed = True  # closed with the rest of the request unread: a reset
        except socket.timeout:
            closed = False
        t.check(closed, "over-long request closed")
        raw.close()
        t.check(http(addr, "/metrics")[0] == 200, "still serving")
    finally:
        t.check(d.stop() == 0, "clean exit")
    log = d.log()
    lines = [ln for ln in log.splitlines() if " SLEEP " in ln]
    ok = [ln for ln in lines if re.search(r"SLEEP \d+ subject 0{16}: ok in \d+ ms", ln)]
    t.check(len(ok) == 3, "3 ok lines: %s" % lines)
    t.check(any("ERR_DEADLINE in" in ln for ln in lines), "deadline line")
    t.check(any("refused: ERR_INVALID_ARGUMENT" in ln for ln in lines), "refusal line")
    t.check(all(ln.startswith("<6>") for ln in lines), "at info level")
    t.check(not any("HEALTH" in ln for ln in log.splitlines()), "HEALTH not logged at info")

    # On a Unix socket (e.g. for a node exporter's textfile or a local agent).
    d = Daemon(daemon, [])
    msock = os.path.join(d.dir, "m.sock")
    d.args = ["--set", "metrics=unix:" + msock]
    d.start()
    try:
        out = unix_request(msock, b"GET /metrics HTTP/1.0\r\n\r\n")
        t.check(out.startswith("HTTP/1.0 200 OK") and "gazesplatd_req_sleep_total 0" in out,
                "unix scrape: %r" % out[:80])
        head = unix_request(msock, b"HEAD /metrics HTTP/1.0\r\n\r\n")
        t.check(head.startswith("HTTP/1.0 200 OK") and head.endswith("\r\n\r\n"), "HEAD: headers only")
    finally:
        d.stop()
    t.check(not os.path.exists(msock), "metrics socket removed at exit")
    sys.exit(t.status())


if __name__ == "__main__":
    main()
