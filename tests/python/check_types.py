"""mypy --strict over the built package gazesplat (the build tree's
python/, the working directory), with clients/python/pyproject.toml's
settings. Exit 77 (skipped) without mypy (Debian: mypy).
usage: check_types.py PYPROJECT"""
import shutil
import subprocess
import sys


def main():
    mypy = shutil.which("mypy")
    if mypy is None:
        print("mypy not installed (scripts/install-deps.sh): skipped")
        return 77
    r = subprocess.run([mypy, "--config-file", sys.argv[1], "--cache-dir", ".mypy_cache", "-p", "gazesplat"],
                       capture_output=True, text=True, timeout=110)
    print(r.stdout, r.stderr)
    return 0 if r.returncode == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
