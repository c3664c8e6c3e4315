"""Compatibility module: the blocking client of the package gazesplat
(gazesplat.client) under its former name, for scripts that put
clients/python on sys.path. New code: `from gazesplat import Client`.

The package is imported as installed (pip install clients/python, or the
Debian package), else from $GAZESPLAT_PB2_DIR or the build tree's python/
directory (CMake builds the package there, messages included).
"""
import os
import sys


def _locate():
    try:
        import gazesplat  # noqa: F401
        return
    except ImportError as e:
        first = e
    here = os.path.dirname(os.path.abspath(__file__))
    for d in (os.environ.get("GAZESPLAT_PB2_DIR"), os.path.join(here, "..", "..", "build", "python")):
        if d and os.path.exists(os.path.join(d, "gazesplat", "gazesplat_pb2.py")):
            sys.path.insert(0, os.path.abspath(d))
            return
    raise first


_locate()

from gazesplat.client import *  # noqa: E402,F401,F403
from gazesplat.client import _angles, _image, pb  # noqa: E402,F401
from gazesplat.protocol import image_array  # noqa: E402,F401
