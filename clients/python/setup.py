"""Build step of the gazesplat package (the metadata is in pyproject.toml):
generates gazesplat/gazesplat_pb2.py (+ .pyi) from the project's
proto/gazesplat.proto with protoc, and gazesplat/_version.py from the
project's version, into the build directory.

    $GAZESPLAT_PROTO   the .proto (default: ../../proto/gazesplat.proto)
    $PROTOC            the compiler (default: protoc on PATH)
    $GAZESPLAT_VERSION the version (default: the top CMakeLists.txt's)
"""
import os
import re
import shutil
import subprocess
import tempfile

from setuptools import setup
from setuptools.command.build_py import build_py

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.normpath(os.path.join(HERE, "..", ".."))


def project_version():
    v = os.environ.get("GAZESPLAT_VERSION")
    if v:
        return v
    path = os.path.join(ROOT, "CMakeLists.txt")
    try:
        m = re.search(r"project\(\s*gazesplat\s+VERSION\s+([0-9][0-9.]*)", open(path).read())
    except OSError:
        m = None
    if not m:
        raise SystemExit("gazesplat: no version: set GAZESPLAT_VERSION or build from the project tree "
                         "(%s)" % path)
    return m.group(1)


def find_proto():
    path = os.environ.get("GAZESPLAT_PROTO") or os.path.join(ROOT, "proto", "gazesplat.proto")
    if not os.path.isfile(path):
        raise SystemExit("gazesplat: %s not found: build from the project's source tree or set "
                         "GAZESPLAT_PROTO" % path)
    return path


def protoc_minor(protoc):
    """The protobuf release of protoc: 'libprotoc 3.21.12' -> 21, 'libprotoc 25.1' -> 25."""
    out = subprocess.run([protoc, "--version"], capture_output=True, text=True, check=True).stdout
    m = re.search(r"(\d+)\.(\d+)", out)
    if not m:
        raise SystemExit("gazesplat: cannot read %s --version: %r" % (protoc, out))
    major, minor = int(m.group(1)), int(m.group(2))
    return minor if major == 3 else major


def check_runtime(protoc):
    """Code from a protoc newer than the protobuf runtime may not load: refuse."""
    try:
        import google.protobuf as gp
    except ImportError:
        return  # the runtime is a dependency, installed later
    m = re.match(r"(\d+)\.(\d+)", gp.__version__)
    runtime = int(m.group(2)) if m else 0
    made = protoc_minor(protoc)
    if made > runtime:
        raise SystemExit("gazesplat: %s (release %d) is newer than the protobuf runtime %s: its code "
                         "may not load; use a protoc of the runtime's release" % (protoc, made,
                                                                                  gp.__version__))


def generate(out_dir, version):
    """gazesplat_pb2.py, gazesplat_pb2.pyi and _version.py into out_dir
    (the package's directory in the build tree)."""
    protoc = os.environ.get("PROTOC") or shutil.which("protoc")
    if not protoc:
        raise SystemExit("gazesplat: protoc not found (Debian: apt-get install protobuf-compiler; "
                         "or set PROTOC)")
    check_runtime(protoc)
    proto = find_proto()
    os.makedirs(out_dir, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        # The .proto as gazesplat/gazesplat.proto: the module is then
        # gazesplat.gazesplat_pb2 (its classes pickle under that name).
        os.makedirs(os.path.join(tmp, "in", "gazesplat"))
        shutil.copyfile(proto, os.path.join(tmp, "in", "gazesplat", "gazesplat.proto"))
        os.makedirs(os.path.join(tmp, "out"))
        subprocess.run([protoc, "-I", os.path.join(tmp, "in"), "--python_out", os.path.join(tmp, "out"),
                        "--pyi_out", os.path.join(tmp, "out"), "gazesplat/gazesplat.proto"], check=True)
        for name in ("gazesplat_pb2.py", "gazesplat_pb2.pyi"):
            shutil.copyfile(os.path.join(tmp, "out", "gazesplat", name), os.path.join(out_dir, name))
    with open(os.path.join(out_dir, "_version.py"), "w") as f:
        f.write('__version__ = "%s"\n' % version)


class BuildPy(build_py):
    def run(self):
        super().run()
        generate(os.path.join(self.build_lib, "gazesplat"), self.distribution.get_version())


setup(version=project_version(), cmdclass={"build_py": BuildPy})
