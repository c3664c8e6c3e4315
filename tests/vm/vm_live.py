#!/usr/bin/env python3
"""VM tier: boots Debian 12's kernel under qemu (TCG, no KVM) with an
initramfs holding `gazesplat live`, its shared libraries, v4l2-ctl, busybox
and the vivid/v4l2loopback module chain; guest_init.sh runs the checks and
this script hot-plugs a USB device through the qemu monitor when the guest
asks. Needs no root. Exit 0 when the guest reports RESULT PASS.

usage: vm_live.py --cli PATH --cache DIR --work DIR [--timeout S] [--stall S]
"""
import argparse
import os
import queue
import shutil
import socket
import stat
import subprocess
import sys
import threading
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))


def newc(entries, out_path):
    """Writes a cpio 'newc' archive: entries are (name, mode, data|target)."""
    with open(out_path, "wb") as out:
        def put(name, mode, data, ino):
            nb = name.encode() + b"\0"
            hdr = "070701" + "".join("%08X" % v for v in (
                ino, mode, 0, 0, 1, 0, len(data), 0, 0, 0, 0, len(nb), 0))
            out.write(hdr.encode() + nb)
            out.write(b"\0" * ((4 - (110 + len(nb)) % 4) % 4))
            out.write(data)
            out.write(b"\0" * ((4 - len(data) % 4) % 4))
        for ino, (name, mode, data) in enumerate(entries, 1):
            put(name, mode, data, ino)
        put("TRAILER!!!", 0, b"", 0)


def ldd(binary, extra_paths=()):
    env = dict(os.environ)
    if extra_paths:
        env["LD_LIBRARY_PATH"] = ":".join(extra_paths)
    text = subprocess.run(["ldd", binary], capture_output=True, text=True, env=env,
                          check=True).stdout
    libs = []
    for line in text.splitlines():
        parts = line.split()
        if "not found" in line:
            raise SystemExit("vm: %s needs a missing library: %s" % (binary, line.strip()))
        if "=>" in parts and len(parts) >= 3 and parts[2].startswith("/"):
            libs.append(parts[2])
        elif parts and parts[0].startswith("/"):
            libs.append(parts[0])
    return libs


def build_initramfs(args, krel, out_path):
    cache_root = os.path.join(args.cache, "root")
    mods = os.path.join(cache_root, "lib/modules", krel)
    files = {}  # guest path -> host path
    dirs = {"bin", "usr", "usr/bin", "usr/lib", "proc", "sys", "dev", "tmp", "modules",
            "lib", "lib64", "etc"}
    files["bin/busybox"] = shutil.which("busybox") or "/bin/busybox"
    files["usr/bin/gazesplat"] = args.cli
    v4l2ctl = shutil.which("v4l2-ctl") or "/usr/bin/v4l2-ctl"
    files["usr/bin/v4l2-ctl"] = v4l2ctl
    for b in (args.cli, v4l2ctl):
        for lib in ldd(b):
            files[lib.lstrip("/")] = lib
    # udevd is udevadm called by that name; libusb's hotplug needs its events.
    udevadm = os.path.join(cache_root, "bin/udevadm")
    if os.path.exists(udevadm):
        shared = os.path.join(cache_root, "usr/lib/x86_64-linux-gnu/systemd")
        try:
            for lib in ldd(udevadm, [shared]):
                guest = lib[len(cache_root):] if lib.startswith(cache_root) else lib
                files[guest.lstrip("/")] = lib
            files["usr/lib/systemd/systemd-udevd"] = udevadm
        except (SystemExit, subprocess.CalledProcessError) as e:
            print("vm: no udevd in the guest (%s)" % e, file=sys.stderr)
    # Module chains in load order, with the parameters the test needs.
    order = []
    params = {"vivid": "n_devs=1 node_types=0x1",
              "v4l2loopback": "video_nr=9 exclusive_caps=1 max_buffers=2 card_label=gazesplat",
              "xhci_pci": ""}
    for top, p in params.items():
        out = subprocess.run(["/sbin/modprobe", "-d", cache_root, "-S", krel,
                              "--show-depends", top], capture_output=True, text=True,
                             check=True).stdout
        for line in out.splitlines():
            if not line.startswith("insmod "):
                continue
            ko = line.split()[1]
            base = os.path.basename(ko)
            if base in [o[0] for o in order]:
                continue
            files["modules/" + base] = ko
            name = base[:-3].replace("-", "_")
            order.append((base, p if name == top else ""))
    for g in list(files):
        d = os.path.dirname(g)
        while d:
            dirs.add(d)
            d = os.path.dirname(d)
    entries = [(d, stat.S_IFDIR | 0o755, b"") for d in sorted(dirs)]
    for g, h in sorted(files.items()):
        with open(h, "rb") as f:
            entries.append((g, stat.S_IFREG | 0o755, f.read()))
    with open(os.path.join(HERE, "guest_init.sh"), "rb") as f:
        entries.append(("init", stat.S_IFREG | 0o755, f.read()))
    order_txt = "".join("%s %s\n" % o for o in order).encode()
    entries.append(("modules/order", stat.S_IFREG | 0o644, order_txt))
    newc(entries, out_path)
    return sum(len(e[2]) for e in entries)


def monitor(sock_path, cmd):
    s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    s.connect(sock_path)
    s.settimeout(2)
    try:
        s.recv(4096)
    except socket.timeout:
        pass
    s.sendall((cmd + "\n").encode())
    time.sleep(0.3)
    try:
        reply = s.recv(4096).decode(errors="replace")
    except socket.timeout:
        reply = ""
    s.close()
    return reply


def tail(path, n):
    try:
        with open(path, errors="replace") as f:
            return f.read().splitlines()[-n:]
    except OSError:
        return []


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--cli", required=True)
    ap.add_argument("--cache", required=True)
    ap.add_argument("--work", required=True)
    ap.add_argument("--timeout", type=float, default=600,
                    help="whole run, boot included (s)")
    ap.add_argument("--stall", type=float, default=240,
                    help="longest wait for the next line on the serial console (s)")
    args = ap.parse_args()
    os.makedirs(args.work, exist_ok=True)
    prep = subprocess.run([os.path.join(ROOT, "scripts/vm/prepare.sh"), args.cache],
                          capture_output=True, text=True)
    if prep.returncode != 0:
        print(prep.stdout + prep.stderr, file=sys.stderr)
        print("vm: scripts/vm/prepare.sh failed", file=sys.stderr)
        return 1
    krel = prep.stdout.split()[-1]
    initrd = os.path.join(args.work, "initramfs.cpio")
    t0 = time.time()
    size = build_initramfs(args, krel, initrd)
    print("vm: initramfs %.0f MB in %.1f s" % (size / 1e6, time.time() - t0))
    kernel = os.path.join(args.cache, "root/boot/vmlinuz-" + krel)
    t_end = time.time() + args.timeout
    for attempt in (1, 2):
        result, reached_init = boot(args, kernel, initrd, t_end, attempt)
        if reached_init or attempt == 2:
            break
        # The kernel died or hung before /init ran: the emulated machine,
        # not gazesplat (under TCG on a starved host the early timer checks
        # can fail). Boot once more; the console above says what happened.
        print("vm: the guest never reached /init; booting once more", flush=True)
    return 0 if result == "PASS" else 1


# no_timer_check: the kernel's IO-APIC timer test can fail when the host
# starves the emulated CPU ("IO-APIC + timer doesn't work!", a panic at
# boot, seen in CI); the guest's timers work regardless.
BASE_APPEND = "console=ttyS0 panic=-1 loglevel=4 rdinit=/init no_timer_check"


def boot(args, kernel, initrd, t_end, attempt, append=BASE_APPEND, mem_mb=1536):
    """One qemu run. Returns (the guest's RESULT or None, whether /init ran).
    The guest speaks in console lines starting "GS-VM:"; "GS-VM: HOTPLUG-READY"
    asks for a USB keyboard on the xhci bus, "GS-VM: RESULT X" is the verdict.
    vm_systemd.py boots its guest through this too (another append)."""
    mon = os.path.join(args.work, "monitor.sock")
    if os.path.exists(mon):
        os.unlink(mon)
    cmd = ["qemu-system-x86_64", "-accel", "tcg,thread=multi", "-cpu", "max", "-smp", "2",
           "-m", str(mem_mb), "-display", "none", "-no-reboot", "-nodefaults",
           "-serial", "stdio", "-monitor", "unix:%s,server,nowait" % mon,
           "-device", "qemu-xhci,id=xhci",
           "-kernel", kernel, "-initrd", initrd,
           "-append", append]
    log_path = os.path.join(args.work, "serial%s.log" % ("" if attempt == 1 else "-%d" % attempt))
    t_start = time.time()
    qemu = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            stdin=subprocess.DEVNULL)
    # The console is read by a thread so that the time limits hold even when
    # the guest prints nothing (a hung boot, a hung guest step).
    lines = queue.Queue()

    def reader():
        for raw in qemu.stdout:
            lines.put(raw.decode(errors="replace").rstrip("\r\n"))
        lines.put(None)

    threading.Thread(target=reader, daemon=True).start()
    result = None
    t_result = 0.0
    why = None
    reached_init = False
    last_step = "(nothing yet: the kernel is booting)"
    t_line = t_start
    with open(log_path, "w") as log:
        while True:
            now = time.time()
            wait = min(t_end, t_line + args.stall) - now
            if result is not None:  # the verdict is in: only the power-off is left
                wait = min(wait, t_result + 20 - now)
                if wait <= 0:
                    print("vm: qemu did not stop within 20 s of the result; killed",
                          flush=True)
                    break
            if wait <= 0:
                if now >= t_end:
                    why = "the run passed its %.0f s limit" % args.timeout
                else:
                    why = "the console was silent for %.0f s" % args.stall
                break
            try:
                line = lines.get(timeout=wait)
            except queue.Empty:
                continue
            if line is None:
                break
            t_line = time.time()
            log.write(line + "\n")
            log.flush()
            if "GS-VM:" in line:
                reached_init = True
                last_step = line[line.index("GS-VM:"):]
                print("%6.1f s  %s" % (t_line - t_start, last_step), flush=True)
            if "GS-VM: HOTPLUG-READY" in line:
                added = monitor(mon, "device_add usb-kbd,id=hp0,bus=xhci.0")
                print("vm: monitor device_add usb-kbd: %s" % added.strip()[-80:], flush=True)
            if "GS-VM: RESULT" in line:
                result = line.split("RESULT")[1].strip()
                t_result = t_line
    if why:
        print("vm: %s; the last step the guest reported: %s" % (why, last_step), flush=True)
    if qemu.poll() is None:
        qemu.kill()
    try:
        qemu.wait(timeout=30)
    except subprocess.TimeoutExpired:
        qemu.kill()
        qemu.wait()
    print("vm: qemu ran %.1f s; serial log in %s" % (time.time() - t_start, log_path), flush=True)
    if result != "PASS":
        print("vm: the console's last lines:")
        print("\n".join(tail(log_path, 60)), flush=True)
    return result, reached_init

if __name__ == "__main__":
    sys.exit(main())
