#!/usr/bin/env python3
"""systemd tier (label vm): boots Debian 12's kernel under qemu (TCG, no KVM)
with the host's systemd as PID 1 and the .deb that cpack makes from the
build in the guest root. systemd_guest.sh, started by the guest's systemd
as a service, installs it with docs/usage.md's commands as written (apt
install ./FILE.deb offline, usermod -aG gazesplat USER, systemctl enable
--now gazesplatd.socket, gazesplat client health --addr ...), then checks
socket activation, the socket's group, the sandbox, the watchdog, reload,
stop and a USB hot-plug reaching the daemon's live pipeline under the
shipped unit. The shipped units are used unmodified; the configuration (a
conffile) gets the live keys appended, as an administrator would. Needs no
root. Exit 0 when the guest reports RESULT PASS.

The guest root is one uncompressed initramfs (the kernel's rootfs): the
files of the host's systemd, libsystemd-shared, apt, dpkg, perl-base and
init-system-helpers, util-linux's setpriv, procps' kill, usermod, busybox
and v4l2-ctl, udev from the VM cache (scripts/vm/prepare.sh), the ELF
libraries all of them and the package need (ldd), the host's dpkg status
(its packages meet the .deb's Depends), the module chains of v4l2loopback
and xhci_pci with a modules.dep made here, and the .deb.

usage: vm_systemd.py --build DIR --cache DIR --work DIR [--timeout S] [--stall S]
"""
import argparse
import concurrent.futures
import io
import os
import re
import shutil
import stat
import subprocess
import sys
import tarfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
sys.path.insert(0, HERE)
import vm_live  # noqa: E402

# The host packages whose files make the guest's userland (dpkg -L).
# apt, dpkg, perl-base and init-system-helpers (deb-systemd-helper and
# deb-systemd-invoke, which the package's maintainer scripts run) install the
# .deb as a user does.
HOST_PACKAGES = ["systemd", "libsystemd-shared", "libsystemd0", "apt", "libapt-pkg6.0", "dpkg",
                 "perl-base", "init-system-helpers"]
SYSTEMD_LIBDIR = "/usr/lib/x86_64-linux-gnu/systemd"
# mount and umount: the API file system units (dev-mqueue.mount ...) run them.
HOST_FILES = ["/usr/bin/busybox", "/usr/bin/setpriv", "/usr/bin/kill", "/usr/bin/v4l2-ctl",
              "/usr/bin/mount", "/usr/bin/umount",
              # dpkg wants ldconfig in PATH (and GNU tar, rm, diff over busybox's);
              # usermod adds the user to the socket's group, reading login.defs.
              "/usr/sbin/ldconfig", "/usr/bin/tar", "/usr/bin/rm", "/usr/bin/diff",
              "/usr/sbin/usermod", "/etc/login.defs"]
# Packages unpacked in the VM cache (the host has no udev). Its
# libsystemd-shared stays there: the host's systemd binaries need the host's
# (the same file name for every 252.x), and udev links against that name.
CACHE_DEBS = ["udev"]
# Host paths not worth carrying into the guest.
SKIP = re.compile(r"^/usr/share/(doc|man|locale|info|lintian|bash-completion|zsh|fish|polkit-1)/")
# What the live pipeline is pointed at: qemu's usb-kbd (0627:0001), which
# vm_live.boot hot-plugs on HOTPLUG-READY, and the loopback the shipped
# modprobe.d options make (/dev/video9).
LIVE_CONF = """
# Added by the VM tier (tests/vm/vm_systemd.py): the live pipeline waits for
# qemu's USB keyboard as its camera (it only needs the hot-plug event) and
# writes to the loopback; no landmark model in the guest (libdlib-data).
live.device = usb:0627:0001
live.output = /dev/video9
photo_input = no
"""
TEST_UNIT = """[Unit]
Description=gazesplat VM tier checks (tests/vm/systemd_guest.sh)
After=sockets.target systemd-modules-load.service systemd-sysusers.service
After=systemd-udev-trigger.service systemd-journald.service

[Service]
Type=simple
ExecStart=/usr/bin/busybox sh /usr/lib/gs-vm/systemd_guest.sh
StandardOutput=tty
StandardError=tty
TTYPath=/dev/ttyS0
"""
# Units the guest cannot use (no agetty, no D-Bus): masked on the kernel
# command line instead of failing at every boot.
MASK = ["serial-getty@ttyS0.service", "getty@tty1.service", "systemd-logind.service"]


class Root:
    """The guest tree: guest path (no leading slash) -> (kind, source, mode).
    kind 'f': source is a host file to copy; 'd': a directory; 'l': source
    is the link's target; 'b': source is the bytes. mode None: the default."""

    def __init__(self):
        self.entries = {}
        # Debian 12 is merged-/usr: /bin, /sbin, /lib, /lib64 are links into /usr.
        self.merged = {}
        for top in ("bin", "sbin", "lib", "lib64"):
            target = os.readlink("/" + top) if os.path.islink("/" + top) else None
            if target:
                self.merged[top] = target.strip("/")
                self.entries[top] = ("l", target, None)

    def canon(self, path):
        parts = path.strip("/").split("/", 1)
        if parts[0] in self.merged:
            parts[0] = self.merged[parts[0]]
        return "/".join(parts)

    def add(self, guest, kind, source, mode=None):
        if guest.strip("/") in self.merged:  # /lib itself: the link made above
            return
        g = self.canon(guest)
        if not g:
            return
        self.entries[g] = (kind, source, mode)
        d = os.path.dirname(g)
        while d and d not in self.entries:
            self.entries[d] = ("d", None, None)
            d = os.path.dirname(d)

    def add_path(self, guest, host):
        """A host path as it is: directory, link or file."""
        st = os.lstat(host)
        if stat.S_ISLNK(st.st_mode):
            self.add(guest, "l", os.readlink(host))
        elif stat.S_ISDIR(st.st_mode):
            if self.canon(guest) not in self.entries:
                self.add(guest, "d", None, stat.S_IMODE(st.st_mode))
        elif stat.S_ISREG(st.st_mode):
            self.add(guest, "f", host, stat.S_IMODE(st.st_mode))

    def add_tree(self, guest_top, host_top):
        for dirpath, dirnames, filenames in os.walk(host_top):
            rel = os.path.relpath(dirpath, host_top)
            for name in dirnames + filenames:
                self.add_path(os.path.join(guest_top, rel, name), os.path.join(dirpath, name))

    def elf_files(self):
        out = []
        for g, e in self.entries.items():
            if e[0] == "f":
                with open(e[1], "rb") as f:
                    if f.read(4) == b"\x7fELF":
                        out.append(e[1])
        return out

    def write_cpio(self, out_path):
        dirs = sorted(g for g, e in self.entries.items() if e[0] == "d")
        rest = sorted(g for g, e in self.entries.items() if e[0] != "d")
        items = []
        for g in dirs:
            mode = self.entries[g][2]
            items.append((g, stat.S_IFDIR | (mode if mode is not None else 0o755), b""))
        for g in rest:
            kind, src, mode = self.entries[g][0], self.entries[g][1], self.entries[g][2]
            if kind == "l":
                items.append((g, stat.S_IFLNK | 0o777, src.encode()))
            elif kind == "b":
                items.append((g, stat.S_IFREG | (mode or 0o644), src))
            else:
                with open(src, "rb") as f:
                    items.append((g, stat.S_IFREG | (mode or 0o644), f.read()))
        vm_live.newc(items, out_path)
        return sum(len(i[2]) for i in items)


def run(cmd, **kw):
    r = subprocess.run(cmd, capture_output=True, text=True, **kw)
    if r.returncode != 0:
        raise SystemExit("vm: %s failed (rc %d):\n%s%s" % (" ".join(cmd), r.returncode,
                                                          r.stdout[-2000:], r.stderr[-2000:]))
    return r.stdout


def build_deb(build, out):
    """The .deb a user installs: cpack from the build tree, as
    tests/integration/test_package.py runs it (docs/usage.md: cd build && cpack)."""
    shutil.rmtree(out, ignore_errors=True)
    os.makedirs(out)
    run(["cpack", "-G", "DEB", "-B", out, "--config", os.path.join(build, "CPackConfig.cmake")],
        cwd=build, timeout=400)
    debs = [f for f in os.listdir(out) if f.endswith(".deb")]
    if len(debs) != 1:
        raise SystemExit("vm: cpack made %s in %s" % (debs, out))
    return os.path.join(out, debs[0])


def inspect_deb(deb, tree):
    """The package's files, unpacked on the host only to be read: the model
    its configuration names and the ELF files whose libraries the guest needs.
    The guest gets the .deb itself."""
    shutil.rmtree(tree, ignore_errors=True)
    run(["dpkg-deb", "-x", deb, tree])
    conf = os.path.join(tree, "etc/gazesplat/gazesplatd.conf")
    if not os.path.exists(conf):
        raise SystemExit("vm: the package holds no etc/gazesplat/gazesplatd.conf")
    # The model the installed configuration names must be in the package (the
    # name of the default model may change; it is read, never assumed).
    m = re.search(r"^model\s*=\s*(\S+)", open(conf).read(), re.M)
    if not m or not os.path.isfile(tree + m.group(1)):
        raise SystemExit("vm: the package's configuration names no packaged model (%s)" %
                         (m.group(1) if m else "no model line"))
    elfs = []
    for dirpath, _, files in os.walk(tree):
        for name in files:
            path = os.path.join(dirpath, name)
            if not os.path.islink(path):
                with open(path, "rb") as f:
                    if f.read(4) == b"\x7fELF":
                        elfs.append(path)
    return m.group(1), elfs


def add_dpkg_database(root):
    """What apt and dpkg need offline: the host's /var/lib/dpkg/status (the
    guest is made of the host's files, whose packages satisfy the .deb's
    Depends), the file lists of the packages carried into the guest (an empty
    list for the others: none of their files is there), an empty
    /var/lib/apt/lists (no repository: the local .deb is the only candidate)
    and apt's own /etc/apt (HOST_PACKAGES)."""
    root.add("var/lib/dpkg/status", "f", "/var/lib/dpkg/status", 0o644)
    for f in ("available", "diversions", "statoverride"):
        root.add("var/lib/dpkg/" + f, "b", b"", 0o644)
    for d in ("updates", "triggers", "alternatives", "info", "parts"):
        root.add("var/lib/dpkg/" + d, "d", None, 0o755)
    carried = set(HOST_PACKAGES)
    names = re.findall(r"^Package: (\S+)\n(?:.+\n)*?Architecture: (\S+)",
                       open("/var/lib/dpkg/status").read(), re.M)
    for name, arch in names:
        for fname in (name + ":" + arch + ".list", name + ".list"):
            host = "/var/lib/dpkg/info/" + fname
            if os.path.exists(host):
                if name in carried:
                    root.add("var/lib/dpkg/info/" + fname, "f", host, 0o644)
                else:
                    root.add("var/lib/dpkg/info/" + fname, "b", b"", 0o644)
                break
    for d in ("var/lib/apt/lists/partial", "var/cache/apt/archives/partial", "var/log/apt"):
        root.add(d, "d", None, 0o755)


def add_packages(root, cache):
    for pkg in HOST_PACKAGES:
        for path in run(["dpkg", "-L", pkg]).splitlines():
            if path in ("/.", "") or SKIP.match(path) or not os.path.lexists(path):
                continue
            root.add_path(path, path)
    for path in HOST_FILES:
        root.add_path(path, os.path.realpath(path))
    cache_root = os.path.join(cache, "root")
    for pkg in CACHE_DEBS:
        debs = sorted(f for f in os.listdir(os.path.join(cache, "debs"))
                      if f.startswith(pkg + "_") and f.endswith(".deb"))
        if not debs:
            raise SystemExit("vm: %s is not in %s/debs (scripts/vm/prepare.sh)" % (pkg, cache))
        tar = subprocess.run(["dpkg-deb", "--fsys-tarfile", os.path.join(cache, "debs", debs[-1])],
                             capture_output=True, check=True).stdout
        with tarfile.open(fileobj=io.BytesIO(tar)) as t:
            for m in t.getmembers():
                name = m.name.lstrip("./")
                if not name or SKIP.match("/" + name):
                    continue
                if m.issym():
                    root.add(name, "l", m.linkname)
                elif m.isfile():
                    root.add(name, "f", os.path.join(cache_root, name), m.mode & 0o7777)


def needed_libraries(elf):
    r = subprocess.run(["file", "-b", elf], capture_output=True, text=True)
    # systemd's private libraries find each other through the binaries' RUNPATH.
    if "dynamically linked" not in r.stdout:  # busybox-static, kernel modules
        return []
    return vm_live.ldd(elf, [SYSTEMD_LIBDIR])


def add_libraries(root, extra_elfs):
    with concurrent.futures.ThreadPoolExecutor(2) as pool:
        for libs in pool.map(needed_libraries, root.elf_files() + extra_elfs):
            for lib in libs:
                if root.canon(lib) not in root.entries:
                    root.add(lib, "f", os.path.realpath(lib), 0o755)


def add_modules(root, cache, krel, work):
    """The v4l2loopback and xhci chains at their usual paths, with a
    modules.dep for just them (depmod -b on a copy)."""
    cache_root = os.path.join(cache, "root")
    modroot = os.path.join(work, "modroot")
    shutil.rmtree(modroot, ignore_errors=True)
    src = os.path.join(cache_root, "lib/modules", krel)
    dst = os.path.join(modroot, "lib/modules", krel)
    os.makedirs(dst)
    for f in ("modules.order", "modules.builtin", "modules.builtin.modinfo"):
        if os.path.exists(os.path.join(src, f)):
            shutil.copy(os.path.join(src, f), dst)
    for top in ("v4l2loopback", "xhci_pci"):
        out = run(["/sbin/modprobe", "-d", cache_root, "-S", krel, "--show-depends", top])
        for line in out.splitlines():
            if line.startswith("insmod "):
                ko = os.path.realpath(line.split()[1])
                rel = os.path.relpath(ko, os.path.realpath(src))
                os.makedirs(os.path.dirname(os.path.join(dst, rel)), exist_ok=True)
                shutil.copy(ko, os.path.join(dst, rel))
    run(["/sbin/depmod", "-b", modroot, krel])
    root.add_tree("usr/lib/modules/" + krel, dst)


def add_config(root, deb):
    # The .deb where a user has it after cpack; the guest installs it with apt.
    root.add("usr/lib/gs-vm/build/" + os.path.basename(deb), "f", deb, 0o644)
    root.add("usr/lib/gs-vm/live.conf", "b", LIVE_CONF.encode(), 0o644)
    root.add("etc/modules-load.d/gs-vm.conf", "b", b"xhci_pci\n", 0o644)
    root.add("etc/passwd", "b", b"root:x:0:0:root:/root:/bin/sh\n"
             b"gsmember:x:1001:1001::/:/bin/sh\ngsother:x:1002:1002::/:/bin/sh\n"
             b"_apt:x:42:65534::/nonexistent:/usr/sbin/nologin\n"
             b"nobody:x:65534:65534:nobody:/nonexistent:/usr/sbin/nologin\n", 0o644)
    root.add("etc/group", "b", b"root:x:0:\ngsmember:x:1001:\ngsother:x:1002:\n"
             b"nogroup:x:65534:\n", 0o644)
    # A fixed machine id: no first-boot presets.
    root.add("etc/machine-id", "b", b"6a5f0e4c2b8d4e1f9a3c7b5d0e2f4a68\n", 0o444)
    root.add("etc/os-release", "f", os.path.realpath("/etc/os-release"), 0o644)
    root.add("etc/systemd/system/default.target", "l", "/usr/lib/systemd/system/multi-user.target")
    root.add("etc/systemd/system/gs-vm-test.service", "b", TEST_UNIT.encode(), 0o644)
    root.add("etc/systemd/system/multi-user.target.wants/gs-vm-test.service", "l",
             "/etc/systemd/system/gs-vm-test.service")
    root.add("usr/lib/gs-vm/systemd_guest.sh", "f", os.path.join(HERE, "systemd_guest.sh"), 0o755)
    root.add("usr/bin/sh", "l", "busybox")
    root.add("init", "l", "/usr/lib/systemd/systemd")
    for d, mode in (("tmp", 0o1777), ("var/tmp", 0o1777), ("var/lib", 0o755), ("var/cache", 0o755),
                    ("var/log", 0o755), ("root", 0o700), ("proc", 0o555), ("sys", 0o555),
                    ("dev", 0o755), ("run", 0o755), ("usr/local/bin", 0o755)):
        root.add(d, "d", None, mode)


def build_initramfs(args, krel, out_path):
    t0 = time.time()
    deb = build_deb(args.build, os.path.join(args.work, "deb"))
    print("vm: cpack made %s in %.1f s" % (os.path.basename(deb), time.time() - t0), flush=True)
    model, elfs = inspect_deb(deb, os.path.join(args.work, "deb-tree"))
    root = Root()
    add_packages(root, args.cache)
    add_dpkg_database(root)
    add_config(root, deb)
    add_modules(root, args.cache, krel, args.work)
    add_libraries(root, elfs)
    return root.write_cpio(out_path), model


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--build", required=True, help="the build tree (cpack makes the .deb there)")
    ap.add_argument("--cache", required=True)
    ap.add_argument("--work", required=True)
    ap.add_argument("--timeout", type=float, default=600, help="whole run, boot included (s)")
    ap.add_argument("--stall", type=float, default=240,
                    help="longest wait for the next line on the serial console (s)")
    args = ap.parse_args()
    args.cache, args.work = os.path.abspath(args.cache), os.path.abspath(args.work)
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
    size, model = build_initramfs(args, krel, initrd)
    print("vm: guest root %.0f MB (model %s) in %.1f s" % (size / 1e6, model, time.time() - t0))
    kernel = os.path.join(args.cache, "root/boot/vmlinuz-" + krel)
    append = vm_live.BASE_APPEND + " systemd.show_status=error" + "".join(
        " systemd.mask=" + u for u in MASK)
    t_end = time.time() + args.timeout
    for attempt in (1, 2):
        result, reached = vm_live.boot(args, kernel, initrd, t_end, attempt, append, 2048)
        if reached or attempt == 2:
            break
        print("vm: the checks never started; booting once more", flush=True)
    return 0 if result == "PASS" else 1


if __name__ == "__main__":
    sys.exit(main())
