"""gazesplatd's resident memory at idle, and its mapped shared libraries.

Starts the daemon (one worker) on the model, waits for its socket and a
further second, prints VmRSS, RssFile (mostly the shared libraries' pages)
and the number of distinct .so files it maps, takes the median of --runs
starts, and stops it.

usage: /usr/bin/python3 bench/daemon/idle_rss.py [--model M] [--build build] [--runs 3]
"""
import argparse
import os
import re
import statistics
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.join(HERE, "..", "..")
sys.path.insert(0, os.path.join(ROOT, "tests", "integration"))
from daemon_util import Daemon  # noqa: E402


def status_kb(pid, field):
    with open("/proc/%d/status" % pid) as f:
        return int(re.search(field + r":\s+(\d+)", f.read()).group(1))


def mapped_libs(pid):
    libs = set()
    with open("/proc/%d/maps" % pid) as f:
        for line in f:
            parts = line.split()
            if len(parts) >= 6 and ".so" in os.path.basename(parts[5]):
                libs.add(parts[5])
    return len(libs)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--model", default=os.path.join(ROOT, "models", "gazegaussian-cpu.safetensors"))
    ap.add_argument("--build", default=os.path.join(ROOT, "build"))
    ap.add_argument("--runs", type=int, default=3)
    a = ap.parse_args()
    rss, rfile, nlib = [], [], []
    for _ in range(a.runs):
        d = Daemon(os.path.join(a.build, "daemon", "gazesplatd"),
                   ["--model", a.model, "--set", "workers=1"]).start()
        try:
            time.sleep(1.0)
            pid = d.proc.pid
            rss.append(status_kb(pid, "VmRSS") / 1024.0)
            rfile.append(status_kb(pid, "RssFile") / 1024.0)
            nlib.append(mapped_libs(pid))
        finally:
            d.stop()
    print("idle VmRSS %.1f MB, RssFile %.1f MB, %d shared libraries mapped (median of %d)"
          % (statistics.median(rss), statistics.median(rfile), int(statistics.median(nlib)),
             a.runs))


if __name__ == "__main__":
    main()
