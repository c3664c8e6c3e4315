"""systemd integration of gazesplatd without PID 1:
  * systemd-analyze verify prints nothing for the units;
  * systemd-analyze security --offline=yes: exposure <= 2.5;
  * socket activation through systemd-socket-activate (LISTEN_FDS), the
    inherited socket is used (no bind) and never unlinked;
  * sd_notify over a datagram NOTIFY_SOCKET bound here: READY=1, STATUS=,
    WATCHDOG=1 at half of WATCHDOG_USEC, STOPPING=1 on SIGTERM.
usage: test_systemd.py GAZESPLATD SYSTEMD_DIR"""
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from daemon_util import Checks, wait_socket  # noqa: E402

CLIENT_DIR = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "clients", "python")
sys.path.insert(0, CLIENT_DIR)


def units_copy(unit_dir, binary, tmp):
    """The units with ExecStart pointing at the built binary (verify checks
    that the executable exists)."""
    for name in ("gazesplatd.service", "gazesplatd.socket"):
        text = open(os.path.join(unit_dir, name)).read().replace("/usr/sbin/gazesplatd", binary)
        with open(os.path.join(tmp, name), "w") as f:
            f.write(text)


def test_verify(t, tmp):
    r = subprocess.run(["systemd-analyze", "verify", "gazesplatd.service", "gazesplatd.socket"],
                       cwd=tmp, capture_output=True, text=True)
    t.check(r.returncode == 0 and r.stdout == "" and r.stderr == "",
            "systemd-analyze verify: rc %d, output %r %r" % (r.returncode, r.stdout, r.stderr))


def test_security(t, tmp):
    r = subprocess.run(["systemd-analyze", "security", "--offline=yes", "--threshold=25",
                        "gazesplatd.service"], cwd=tmp, capture_output=True, text=True)
    m = re.search(r"Overall exposure level for gazesplatd.service: ([0-9.]+)", r.stdout)
    level = float(m.group(1)) if m else 99.0
    print("exposure level", level)
    t.check(r.returncode == 0 and level <= 2.5, "exposure %s (rc %d) > 2.5" % (level, r.returncode))


def recv_notifications(sock, until, want):
    got = []
    while time.time() < until:
        sock.settimeout(max(0.01, until - time.time()))
        try:
            got.append(sock.recv(4096).decode())
        except socket.timeout:
            break
        if want(got):
            break
    return got


def test_activation(t, binary, tmp):
    import gazesplat_client as gc
    api = os.path.join(tmp, "api.sock")
    notify_path = os.path.join(tmp, "notify.sock")
    unused = os.path.join(tmp, "fallback.sock")
    ns = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    ns.bind(notify_path)
    log = open(os.path.join(tmp, "activate.log"), "wb")
    proc = subprocess.Popen(["systemd-socket-activate", "-l", api, "--fdname=api",
                             "-E", "NOTIFY_SOCKET=" + notify_path, "-E", "WATCHDOG_USEC=400000",
                             binary, "--socket", unused, "--set", "debug_requests=yes"],
                            stderr=log)
    try:
        wait_socket(api, proc)
        # The daemon is exec'd on the first connection.
        c = gc.Client("unix:" + api)
        h = c.health()
        t.check(h.state == gc.pb.Health.FAILED and "no model" in h.detail,
                "health over the activated socket: %s" % h)
        c.close()
        msgs = recv_notifications(ns, time.time() + 3.0,
                                  lambda g: sum("WATCHDOG=1" in m for m in g) >= 3)
        text = "\n".join(msgs)
        t.check("READY=1" in text, "READY=1 in %r" % msgs)
        t.check("STATUS=" in text, "STATUS= in %r" % msgs)
        t.check(text.count("WATCHDOG=1") >= 3, "3 watchdog pings within 3 s: %r" % msgs)
        t.check(not os.path.exists(unused), "fell back to binding %s" % unused)
        # SIGHUP: RELOADING=1, then READY=1 once the reload is over.
        proc.send_signal(signal.SIGHUP)
        msgs = recv_notifications(ns, time.time() + 2.0, lambda g: any("READY=1" in m for m in g))
        text = "\n".join(m for m in msgs if "WATCHDOG" not in m)
        t.check("RELOADING=1" in text and text.index("RELOADING=1") < text.rindex("READY=1"),
                "SIGHUP notifications: %r" % msgs)
        proc.send_signal(signal.SIGTERM)
        rc = proc.wait(10)
        msgs = recv_notifications(ns, time.time() + 1.0, lambda g: any("STOPPING=1" in m for m in g))
        t.check(any("STOPPING=1" in m for m in msgs), "STOPPING=1 after SIGTERM: %r" % msgs)
        t.check(rc == 0, "exit status %s" % rc)
        t.check(os.path.exists(api), "the inherited socket was unlinked")
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        log.close()
        if t.failures:
            print(open(os.path.join(tmp, "activate.log"), errors="replace").read())


def main():
    binary, unit_dir = os.path.abspath(sys.argv[1]), sys.argv[2]
    t = Checks()
    tmp = tempfile.mkdtemp(prefix="gsd_sd_")
    try:
        units_copy(unit_dir, binary, tmp)
        if shutil.which("systemd-analyze"):
            test_verify(t, tmp)
            test_security(t, tmp)
        else:
            t.check(False, "systemd-analyze not installed")
        test_activation(t, binary, tmp)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return t.status()


if __name__ == "__main__":
    sys.exit(main())
