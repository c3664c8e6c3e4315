"""Compatibility script: gazesplat.grid (installed as the console script
gazesplat-grid) under its former name:

    python3 clients/python/gazesplat_grid.py --image photo.jpg --out grid.png
"""
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import gazesplat_client  # noqa: E402,F401  (finds the package)
from gazesplat.grid import *  # noqa: E402,F401,F403
from gazesplat.grid import cli  # noqa: E402

if __name__ == "__main__":
    sys.exit(cli(prog="gazesplat_grid"))
