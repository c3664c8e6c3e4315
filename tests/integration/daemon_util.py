"""Helpers for the Python integration tests: start gazesplatd in a temp
directory, wait for its socket, stop it, show its log on failure."""
import os
import signal
import socket
import subprocess
import tempfile
import time


def free_port():
    """A TCP port on 127.0.0.1 free just now."""
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


def unix_request(path, data, timeout=10):
    """Sends data on a Unix stream socket and reads until the peer closes;
    the reply decoded."""
    s = socket.socket(socket.AF_UNIX)
    s.settimeout(timeout)
    s.connect(path)
    s.sendall(data)
    out = b""
    while True:
        b = s.recv(65536)
        if not b:
            break
        out += b
    s.close()
    return out.decode()


class Daemon:
    def __init__(self, binary, args=(), env=None, cwd=None):
        self.dir = tempfile.mkdtemp(prefix="gsd_py_")
        self.sock = os.path.join(self.dir, "s.sock")
        self.log_path = os.path.join(self.dir, "log")
        self.binary = binary
        self.args = list(args)
        self.env = env
        self.proc = None

    def start(self, wait=True):
        log = open(self.log_path, "ab")
        self.proc = subprocess.Popen([self.binary, "--socket", self.sock] + self.args,
                                     stderr=log, env=self.env)
        log.close()
        if wait:
            wait_socket(self.sock, self.proc)
        return self

    def stop(self, sig=signal.SIGTERM, timeout=10):
        if self.proc is None:
            return None
        self.proc.send_signal(sig)
        try:
            rc = self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            rc = self.proc.wait()
        self.proc = None
        return rc

    def log(self):
        with open(self.log_path, errors="replace") as f:
            return f.read()


def wait_socket(path, proc=None, timeout=10.0):
    end = time.time() + timeout
    while time.time() < end:
        if proc is not None and proc.poll() is not None:
            raise RuntimeError("process exited with %s" % proc.returncode)
        s = socket.socket(socket.AF_UNIX)
        try:
            s.connect(path)
            return
        except OSError:
            time.sleep(0.02)
        finally:
            s.close()
    raise RuntimeError("socket %s never answered" % path)


class Checks:
    """Counts failures; prints what differed; exit status for main."""

    def __init__(self):
        self.failures = 0
        self.count = 0

    def check(self, cond, what):
        self.count += 1
        if not cond:
            self.failures += 1
            print("CHECK failed:", what, flush=True)
        return cond

    def status(self):
        print("%d checks, %d failed" % (self.count, self.failures))
        return 1 if self.failures else 0
