"""The Debian package (labels package, slow), never installed on this host:
  * cpack builds gazesplat_VERSION_ARCH.deb from the build tree;
  * dpkg-deb -I/-f: name, version, architecture, Depends (shlibdeps found
    the shared libraries; the data packages the daemon opens by path);
    conffiles and the maintainer scripts (sh -n);
  * dpkg-deb -c: every file at its FHS path (prefix /usr);
  * dpkg-deb -x into a temporary root: the extracted gazesplatd --version
    (= the package version) and gazesplat --help run; the unit's ExecStart
    and --config name files the package holds; the installed configuration
    passes --check-config and names the installed model; the installed
    Python client imports its generated messages; the extracted daemon
    loads the shipped model with the installed configuration and answers
    HEALTH READY; systemd-analyze verify prints nothing for the extracted
    units (ExecStart pointed into the temporary root); the Python package
    imports from the extracted dist-packages (its generated messages, py.typed
    and metadata beside it) and its gazesplat-grid script runs; systemd-sysusers
    --root on the temporary root creates the gazesplat group from the
    packaged sysusers.d file.
usage: test_package.py BUILD_DIR INSTALL_PREFIX"""
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from daemon_util import Checks, Daemon  # noqa: E402

# Relative to the root of the package, for prefix /usr.
FHS = [
    "usr/bin/gazesplat",
    "usr/sbin/gazesplatd",
    "etc/gazesplat/gazesplatd.conf",
    "usr/lib/systemd/system/gazesplatd.service",
    "usr/lib/systemd/system/gazesplatd.socket",
    "usr/lib/sysusers.d/gazesplat.conf",
    "usr/share/gazesplat/models/gazegaussian-cpu.safetensors",
    "usr/share/gazesplat/models/README.md",
    "usr/bin/gazesplat-grid",
    "usr/lib/python3/dist-packages/gazesplat/__init__.py",
    "usr/lib/python3/dist-packages/gazesplat/client.py",
    "usr/lib/python3/dist-packages/gazesplat/aio.py",
    "usr/lib/python3/dist-packages/gazesplat/dataset.py",
    "usr/lib/python3/dist-packages/gazesplat/grid.py",
    "usr/lib/python3/dist-packages/gazesplat/gazesplat_pb2.py",
    "usr/lib/python3/dist-packages/gazesplat/gazesplat_pb2.pyi",
    "usr/lib/python3/dist-packages/gazesplat/py.typed",
    "usr/lib/python3/dist-packages/gazesplat-%s.egg-info/PKG-INFO",
    "usr/share/doc/gazesplat/python/train_gaze_estimator.py",
    "usr/share/gazesplat/samples/astronaut.jpg",
    "usr/share/doc/gazesplat/README.md",
    "usr/share/doc/gazesplat/PROTOCOL.md",
    "usr/share/doc/gazesplat/gazesplatd.md",
    "usr/share/man/man1/gazesplat.1.gz",
    "usr/share/man/man1/gazesplat-grid.1.gz",
    "usr/share/doc/gazesplat/changelog.gz",
    "usr/share/man/man8/gazesplatd.8.gz",
    "usr/share/man/man5/gazesplatd.conf.5.gz",
    "usr/lib/modprobe.d/gazesplat-v4l2loopback.conf",
]
# Shared libraries dpkg-shlibdeps must have found (package name prefixes).
LIB_DEPS = ["libc6", "libopenblas", "libprotobuf-c1", "libopencv-core", "libjpeg62-turbo",
            "libpng16-16", "libusb-1.0-0", "libstdc++6"]
# Decoding goes through libpng and libjpeg directly: imgcodecs (and the GDAL
# it brings) must not come back.
LIB_NOT_DEPS = ["libopencv-imgcodecs"]
DATA_DEPS = ["libdlib-data", "opencv-data", "systemd"]


def run(cmd, **kw):
    return subprocess.run(cmd, capture_output=True, text=True, **kw)


def build_deb(t, build, out):
    r = run(["cpack", "-G", "DEB", "-B", out, "--config", os.path.join(build, "CPackConfig.cmake")],
            cwd=build, timeout=400)
    debs = [f for f in os.listdir(out) if f.endswith(".deb")]
    t.check(r.returncode == 0 and len(debs) == 1, "cpack rc %d, debs %s\n%s%s" % (r.returncode, debs,
                                                                               r.stdout[-3000:], r.stderr[-3000:]))
    # A Release build carries -g: its debug information goes to the dbgsym
    # package (by build id) and the package's binaries are stripped.
    if "CMAKE_BUILD_TYPE:STRING=Release" in open(os.path.join(build, "CMakeCache.txt")).read():
        ddebs = [f for f in os.listdir(out) if f.endswith(".ddeb")]
        t.check(len(ddebs) == 1 and ddebs[0].startswith("gazesplat-dbgsym_"), "dbgsym package: %s" % ddebs)
        if ddebs:
            listed = run(["dpkg-deb", "-c", os.path.join(out, ddebs[0])]).stdout
            t.check(listed.count(".debug") >= 2 and "usr/lib/debug/.build-id/" in listed,
                    "dbgsym contents: %s" % listed[-500:])
    return os.path.join(out, debs[0]) if debs else None


def field(deb, name):
    return run(["dpkg-deb", "-f", deb, name]).stdout.strip()


def check_control(t, deb, tmp):
    info = run(["dpkg-deb", "-I", deb])
    print(info.stdout)
    t.check(info.returncode == 0, "dpkg-deb -I: %s" % info.stderr)
    version, arch = field(deb, "Version"), field(deb, "Architecture")
    t.check(field(deb, "Package") == "gazesplat", "Package %r" % field(deb, "Package"))
    t.check(re.fullmatch(r"\d+\.\d+\.\d+", version) is not None, "Version %r" % version)
    host = run(["dpkg", "--print-architecture"]).stdout.strip()
    t.check(arch == host, "Architecture %r, host %r" % (arch, host))
    t.check(os.path.basename(deb) == "gazesplat_%s_%s.deb" % (version, arch), "file name %s" % deb)
    deps = [d.strip() for d in field(deb, "Depends").split(",")]
    names = [re.split(r"[ (|]", d)[0] for d in deps]
    for want in LIB_DEPS:
        t.check(any(n.startswith(want) for n in names), "Depends lacks %s: %s" % (want, deps))
    for unwanted in LIB_NOT_DEPS:
        t.check(not any(n.startswith(unwanted) for n in names), "Depends has %s: %s" % (unwanted, deps))
    for want in DATA_DEPS:
        t.check(want in names, "Depends lacks %s: %s" % (want, deps))
    ctrl = os.path.join(tmp, "DEBIAN")
    r = run(["dpkg-deb", "-e", deb, ctrl])
    t.check(r.returncode == 0, "dpkg-deb -e: %s" % r.stderr)
    conffiles = open(os.path.join(ctrl, "conffiles")).read().split() if r.returncode == 0 else []
    return version, conffiles, ctrl


def check_scripts(t, ctrl):
    for s in ("postinst", "prerm", "postrm"):
        p = os.path.join(ctrl, s)
        t.check(os.path.exists(p) and os.access(p, os.X_OK), "%s missing or not executable" % s)
        if os.path.exists(p):
            r = run(["sh", "-n", p])
            t.check(r.returncode == 0, "%s: sh -n: %s" % (s, r.stderr))
    if os.path.exists(os.path.join(ctrl, "postinst")):
        text = open(os.path.join(ctrl, "postinst")).read()
        t.check(re.search(r"systemd-sysusers .*gazesplat\.conf", text) is not None,
                "postinst does not create the group")
        # Debian's helpers, not systemctl, for enablement and restarts.
        t.check("deb-systemd-helper" in text and "deb-systemd-invoke try-restart" in text and
                "systemctl try-restart" not in text, "postinst not in debhelper's style")


def check_contents(t, deb, prefix, conffiles, version):
    r = run(["dpkg-deb", "-c", deb])
    t.check(r.returncode == 0, "dpkg-deb -c: %s" % r.stderr)
    listed = {line.split()[-1].lstrip("./") for line in r.stdout.splitlines() if line.split()}
    if prefix != "/usr":
        print("NOTE: build configured with prefix %s: FHS paths checked only for /usr" % prefix)
        return listed
    for p in FHS:
        p = p % version if "%s" in p else p
        t.check(p in listed, "package lacks /%s" % p)
    stale = [p for p in listed if p.startswith("usr/share/gazesplat/python") or "__pycache__" in p]
    t.check(not stale, "stale or compiled Python files: %s" % stale)
    t.check(conffiles == ["/etc/gazesplat/gazesplatd.conf"], "conffiles %s" % conffiles)
    stray = [p for p in listed if p and not p.endswith("/")
             and not p.startswith(("usr/bin/", "usr/sbin/", "usr/lib/", "usr/share/", "etc/gazesplat/"))]
    t.check(not stray, "files outside the FHS layout: %s" % stray)
    return listed


def unit_paths(root, unit_dir):
    """ExecStart's binary and --config file, from the extracted unit."""
    text = open(os.path.join(unit_dir, "gazesplatd.service")).read()
    m = re.search(r"^ExecStart=(\S+) --config (\S+)$", text, re.M)
    return (m.group(1), m.group(2)) if m else (None, None)


def check_extracted(t, deb, root, prefix, version, tmp):
    r = run(["dpkg-deb", "-x", deb, root])
    t.check(r.returncode == 0, "dpkg-deb -x: %s" % r.stderr)
    sbin, binp = root + prefix + "/sbin/gazesplatd", root + prefix + "/bin/gazesplat"
    r = run([sbin, "--version"])
    t.check(r.returncode == 0 and r.stdout.strip() == "gazesplatd " + version,
            "gazesplatd --version: rc %d %r (package %s)" % (r.returncode, r.stdout, version))
    r = run([binp, "--help"])
    t.check(r.returncode == 0 and "usage" in (r.stdout + r.stderr).lower(), "gazesplat --help rc %d" % r.returncode)
    for exe in (sbin, binp):
        r = run(["file", "-b", exe])
        t.check(", stripped" in r.stdout, "%s not stripped: %s" % (exe, r.stdout.strip()))
    unit_dir = os.path.join(root, prefix.lstrip("/"), "lib/systemd/system")
    exe, conf = unit_paths(root, unit_dir)
    t.check(exe is not None and os.access(root + exe, os.X_OK), "ExecStart %s not in the package" % exe)
    t.check(conf is not None and os.path.exists(root + conf), "--config %s not in the package" % conf)
    if conf is None or not os.path.exists(root + conf):
        return sbin, None, unit_dir
    model = re.search(r"^model = (\S+)$", open(root + conf).read(), re.M)
    t.check(model is not None and os.path.exists(root + model.group(1)),
            "configured model %s not in the package" % (model and model.group(1)))
    r = run([sbin, "-c", root + conf, "--check-config"])
    t.check(r.returncode == 0, "--check-config on the installed file: rc %d %s" % (r.returncode, r.stderr))
    return sbin, root + model.group(1) if model else None, unit_dir


def python_env(pydir):
    """The environment of a python3 whose dist-packages is the extracted one."""
    env = {k: v for k, v in os.environ.items() if not k.startswith(("PYTHON", "GAZESPLAT_"))}
    env["PYTHONPATH"] = pydir
    return env


def check_python(t, root, prefix, version):
    """`python3 -c "import gazesplat"` with the extracted dist-packages (the
    host's python3 reads /usr/lib/python3/dist-packages; here PYTHONPATH
    points at the copy in the root), and the packaged console script."""
    pydir = os.path.join(root, prefix.lstrip("/"), "lib/python3/dist-packages")
    env = python_env(pydir)
    r = run([sys.executable, "-c", "import importlib.metadata as m, gazesplat, gazesplat.aio, gazesplat.grid; "
             "print(gazesplat.pb.__file__); print(gazesplat.__version__, m.version('gazesplat'))"],
            env=env, cwd=root)
    lines = r.stdout.split("\n")
    t.check(r.returncode == 0 and lines[0].startswith(os.path.join(pydir, "gazesplat", "")) and
            lines[1] == "%s %s" % (version, version),
            "import gazesplat from the package: rc %d %s %s" % (r.returncode, r.stdout, r.stderr[-800:]))
    r = run([sys.executable, "-c", "import gazesplat.dataset"], env=env, cwd=root)
    t.check(r.returncode == 0, "import gazesplat.dataset (python3-torch): %s" % r.stderr[-800:])
    script = os.path.join(root, prefix.lstrip("/"), "bin", "gazesplat-grid")
    first = open(script).readline().strip() if os.path.exists(script) else ""
    t.check(first == "#!/usr/bin/python3" and os.access(script, os.X_OK), "gazesplat-grid: %r" % first)
    r = run([sys.executable, script, "--help"], env=env, cwd=root)
    t.check(r.returncode == 0 and "usage: gazesplat-grid" in r.stdout,
            "gazesplat-grid --help: rc %d %s" % (r.returncode, r.stderr[-800:]))
    return pydir


def check_daemon(t, sbin, conf, model, pydir):
    """The extracted daemon with the installed configuration and model,
    asked by the extracted Python package."""
    sys.path.insert(0, pydir)
    import gazesplat as gc
    d = Daemon(sbin, ["-c", conf, "--model", model, "--state-dir", tempfile.mkdtemp(prefix="gsd_pkg_"),
                      "--set", "photo_input=no"]).start()
    try:
        state = None
        for _ in range(600):
            with gc.Client("unix:" + d.sock) as c:
                state = c.health().state
            if state != gc.pb.Health.LOADING:
                break
            time.sleep(0.1)
        t.check(state == gc.pb.Health.READY, "installed daemon on the shipped model: state %s" % state)
    finally:
        rc = d.stop()
        if t.failures:
            print(d.log()[-3000:])
    t.check(rc == 0, "daemon exit %s" % rc)


def check_units(t, root, unit_dir, sbin, tmp):
    units = os.path.join(tmp, "units")
    os.makedirs(units)
    for name in ("gazesplatd.service", "gazesplatd.socket"):
        exe = None
        text = open(os.path.join(unit_dir, name)).read()
        m = re.search(r"^ExecStart=(\S+)", text, re.M)
        if m:
            exe = m.group(1)
            text = text.replace(exe, root + exe)
        with open(os.path.join(units, name), "w") as f:
            f.write(text)
    r = run(["systemd-analyze", "verify", "gazesplatd.service", "gazesplatd.socket"], cwd=units)
    t.check(r.returncode == 0 and r.stdout == "" and r.stderr == "",
            "systemd-analyze verify on the extracted units: rc %d %r %r" % (r.returncode, r.stdout, r.stderr))


def check_sysusers(t, root):
    # the packaged file wherever the prefix put it; an etc/ for the lock
    conf = [os.path.join(d, f) for d, _, fs in os.walk(root) for f in fs
            if f == "gazesplat.conf" and d.endswith("sysusers.d")]
    os.makedirs(os.path.join(root, "etc"), exist_ok=True)
    r = run(["systemd-sysusers", "--root=" + root] + (conf[:1] or ["gazesplat.conf"]))
    group = os.path.join(root, "etc", "group")
    lines = open(group).read().splitlines() if os.path.exists(group) else []
    t.check(r.returncode == 0 and any(line.startswith("gazesplat:") for line in lines),
            "systemd-sysusers --root: rc %d %s, group file %s" % (r.returncode, r.stderr, lines))


def main():
    build, prefix = os.path.abspath(sys.argv[1]), sys.argv[2].rstrip("/") or "/"
    for tool in ("cpack", "dpkg-deb", "dpkg-shlibdeps", "systemd-analyze"):
        if shutil.which(tool) is None:
            print("missing %s (scripts/install-deps.sh)" % tool)
            return 1
    t = Checks()
    tmp = tempfile.mkdtemp(prefix="gs_pkg_")
    try:
        deb = build_deb(t, build, os.path.join(tmp, "out"))
        if deb is None:
            return t.status()
        version, conffiles, ctrl = check_control(t, deb, tmp)
        check_scripts(t, ctrl)
        check_contents(t, deb, prefix, conffiles, version)
        root = os.path.join(tmp, "root")
        sbin, model, unit_dir = check_extracted(t, deb, root, prefix, version, tmp)
        pydir = check_python(t, root, prefix, version)
        exe, conf = unit_paths(root, unit_dir)
        if model and conf:
            check_daemon(t, sbin, root + conf, model, pydir)
        check_units(t, root, unit_dir, sbin, tmp)
        check_sysusers(t, root)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return t.status()


if __name__ == "__main__":
    sys.exit(main())
