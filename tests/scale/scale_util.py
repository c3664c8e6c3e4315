"""The scale-out tier's rig: N gazesplatd daemons on loopback TCP behind
HAProxy run with the shipped configuration (deploy/haproxy/gazesplat.cfg),
only its addresses replaced; HAProxy's runtime API for server states and
per-server connection counts."""
import hashlib
import os
import re
import signal
import socket
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.join(HERE, "..", "..")
sys.path.insert(0, os.path.join(ROOT, "tests", "integration"))
from daemon_util import Checks, Daemon, free_port, unix_request  # noqa: E402,F401

SHIPPED_CFG = os.path.join(ROOT, "deploy", "haproxy", "gazesplat.cfg")
MODEL = os.path.join(ROOT, "models", "gazegaussian-cpu.safetensors")


def wait_port(port, proc=None, timeout=20.0):
    end = time.time() + timeout
    while time.time() < end:
        if proc is not None and proc.poll() is not None:
            raise RuntimeError("process exited with %s" % proc.returncode)
        try:
            socket.create_connection(("127.0.0.1", port), timeout=1).close()
            return
        except OSError:
            time.sleep(0.05)
    raise RuntimeError("port %d never answered" % port)


class TcpDaemon(Daemon):
    """gazesplatd on 127.0.0.1:port (no Unix socket), its own state dir;
    stop and log as Daemon's."""

    def __init__(self, binary, name, root, model=MODEL, extra=()):
        self.name = name
        self.port = free_port()
        self.dir = os.path.join(root, name)
        os.makedirs(os.path.join(self.dir, "state"), exist_ok=True)
        self.log_path = os.path.join(self.dir, "log")
        self.argv = [binary, "--socket", "none", "--tcp", "127.0.0.1:%d" % self.port,
                     "--model", model, "--state-dir", os.path.join(self.dir, "state"),
                     "--set", "workers=1"] + list(extra)
        self.proc = None

    @property
    def addr(self):
        return "tcp:127.0.0.1:%d" % self.port

    def start(self):
        with open(self.log_path, "ab") as log:
            self.proc = subprocess.Popen(self.argv, stderr=log, stdout=log)
        wait_port(self.port, self.proc)
        return self

    def kill(self, sig=signal.SIGKILL):
        if self.proc is not None:
            self.proc.send_signal(sig)

    def stop(self, sig=signal.SIGTERM, timeout=15):
        if self.proc is not None and self.proc.poll() is not None:
            rc, self.proc = self.proc.returncode, None  # killed by the test
            return rc
        return super().stop(sig, timeout)


def haproxy_config(text, bind_port, stats_sock, servers, balance=None):
    """The shipped configuration with this rig's addresses: the bind line,
    the stats socket, the server lines (name, port) and no syslog; and,
    for a comparison, another balance line (e.g. "roundrobin")."""
    lines, in_backend, done = [], False, False
    for ln in text.splitlines():
        s = ln.strip()
        if s.startswith("log /dev/log"):
            ln = "    log stderr format short local0 " + os.environ.get("GS_HAPROXY_LOG", "notice")
        if s.startswith("bind "):
            ln = "    bind 127.0.0.1:%d" % bind_port
        elif s.startswith("stats socket "):
            ln = re.sub(r"stats socket \S+", "stats socket " + stats_sock, ln)
        elif s.startswith("balance ") and balance:
            ln = "    balance " + balance
        elif s.startswith("server "):
            if not done:
                for name, port in servers:
                    lines.append("    server %s 127.0.0.1:%d check" % (name, port))
                done = True
            continue
        if s.startswith("backend "):
            in_backend = True
        lines.append(ln)
    if not (in_backend and done):
        raise RuntimeError("shipped config: no backend with server lines")
    return "\n".join(lines) + "\n"


class Haproxy:
    def __init__(self, root, servers, balance=None):
        self.dir = os.path.join(root, "haproxy")
        os.makedirs(self.dir, exist_ok=True)
        self.port = free_port()
        self.stats = os.path.join(self.dir, "admin.sock")
        self.cfg = os.path.join(self.dir, "haproxy.cfg")
        with open(SHIPPED_CFG) as f:
            text = haproxy_config(f.read(), self.port, self.stats, servers, balance)
        with open(self.cfg, "w") as f:
            f.write(text)
        self.log_path = os.path.join(self.dir, "log")
        self.proc = None

    @property
    def addr(self):
        return "tcp:127.0.0.1:%d" % self.port

    def start(self):
        chk = subprocess.run(["haproxy", "-c", "-q", "-f", self.cfg], capture_output=True, text=True)
        if chk.returncode != 0:
            raise RuntimeError("haproxy -c: %s%s" % (chk.stdout, chk.stderr))
        with open(self.log_path, "ab") as log:
            self.proc = subprocess.Popen(["haproxy", "-db", "-f", self.cfg], stdout=log, stderr=log)
        wait_port(self.port, self.proc)
        return self

    def stop(self):
        if self.proc is not None:
            self.proc.terminate()
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
            self.proc = None

    def command(self, cmd):
        return unix_request(self.stats, cmd.encode() + b"\n", timeout=5)

    def servers(self):
        """{server name: {"status": "UP"/"DOWN"/..., "stot": sessions}}."""
        text = self.command("show stat")
        lines = text.splitlines()
        head = lines[0].lstrip("# ").split(",")
        out = {}
        for ln in lines[1:]:
            row = dict(zip(head, ln.split(",")))
            if row.get("pxname") == "gazesplatd" and row.get("svname") not in ("BACKEND", None):
                out[row["svname"]] = {"status": row["status"], "stot": int(row["stot"] or 0),
                                      "check": row.get("check_status", ""), "last_chk": row.get("last_chk", "")}
        return out

    def wait_status(self, want, timeout=20.0):
        """Waits until every server named in want has that status."""
        end = time.time() + timeout
        while time.time() < end:
            st = self.servers()
            # "UP 1/2": not checked yet, or a check failed; "DOWN 1/2": rising.
            if all(st.get(n, {}).get("status") == w and st[n]["check"] != "INI"
                   for n, w in want.items()):
                return st
            time.sleep(0.05)
        return self.servers()

    def log(self):
        with open(self.log_path, errors="replace") as f:
            return f.read()


def digest_of(keys):
    """The Health.subjects_digest of a set of keys, as PROTOCOL.md defines it."""
    d = bytearray(16)
    for k in keys:
        for i, b in enumerate(hashlib.blake2b(k, digest_size=16).digest()):
            d[i] ^= b
    return bytes(d)


def synth_faces(cli, work, count, size=256):
    out = os.path.join(work, "faces%d_%d" % (size, count))
    if not os.path.exists(os.path.join(out, "labels.jsonl")):
        subprocess.run([cli, "synth", "--out", out, "--count", str(count), "--size", str(size),
                        "--seed-split", "test", "--identities", str(count), "--no-masks"],
                       check=True, capture_output=True)
    names = sorted(os.listdir(os.path.join(out, "images")))
    return [open(os.path.join(out, "images", n), "rb").read() for n in names]


def workdir(prefix):
    return tempfile.mkdtemp(prefix=prefix)
