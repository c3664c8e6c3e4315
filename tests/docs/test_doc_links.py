#!/usr/bin/env python3
"""Every link and repository path the tree names must exist.

Two checks over the files git tracks (or, outside a git checkout, every
file under the root):
  1. every relative Markdown link, [text](target) or ![alt](target), in a
     .md file resolves to a file or folder (the #fragment is not checked);
  2. every path under bench/, experiments/, docs/ or models/ named anywhere
     in a text file (prose, comments, strings, scripts) exists. Brace lists
     ({val,test}-x.md) are expanded and each member must exist; a name with
     * or ? must match at least one file. Paths inside another path
     (build/bench/..., $ROOT/bench/...) are not repository paths and are
     skipped. The experiment notes under experiments/ record their commands
     as they ran, naming model files by their names of the day (git history
     keeps those files), so their models/ paths are not checked.

Usage: test_doc_links.py [ROOT]. Exits 1 and lists each broken reference as
FILE:LINE: what. test_doc_links.py --self-test runs the checks on a made-up
tree with known broken references and fails unless it finds exactly those.
"""
import glob
import os
import re
import subprocess
import sys

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", ".."))
TEXT_EXT = (".md", ".c", ".h", ".py", ".sh", ".txt", ".cmake", ".conf", ".cfg",
            ".proto", ".service", ".socket", ".in", ".toml", ".jsonl", "")
SKIP_DIRS = ("assets/",)

LINK = re.compile(r"!?\[[^\]\n]*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")
# A repository path: not preceded by a character that would make it part of
# a longer path, a variable or a word.
PATH = re.compile(r"(?<![\w/.$}~-])((?:bench|experiments|docs|models)/[\w./{},*?+-]*)")


def tracked_files():
    try:
        out = subprocess.run(["git", "-C", ROOT, "ls-files", "-z"], check=True,
                             capture_output=True).stdout.decode()
        files = [f for f in out.split("\0") if f]
    except (OSError, subprocess.CalledProcessError):
        files = []
        for d, _, names in os.walk(ROOT):
            if "/." in d or "/build" in d:
                continue
            files += [os.path.relpath(os.path.join(d, n), ROOT) for n in names]
    return [f for f in files
            if not f.startswith(SKIP_DIRS) and os.path.isfile(os.path.join(ROOT, f))]


def is_text(rel):
    base = os.path.basename(rel)
    ext = os.path.splitext(base)[1]
    return ext in TEXT_EXT or base in ("CMakeLists.txt", "run")


def expand(path):
    m = re.search(r"\{([^{}]*)\}", path)
    if not m:
        return [path]
    out = []
    for alt in m.group(1).split(","):
        out += expand(path[:m.start()] + alt + path[m.end():])
    return out


def exists(rel):
    full = os.path.join(ROOT, rel)
    if any(c in rel for c in "*?"):
        return bool(glob.glob(full))
    return os.path.exists(full)


def split_tokens(token):
    """Commas outside braces separate paths (--model a,b); trailing
    sentence punctuation is not part of a path."""
    out, depth, cur = [], 0, ""
    for c in token:
        depth += (c == "{") - (c == "}")
        if c == "," and depth == 0:
            out.append(cur)
            cur = ""
        else:
            cur += c
    out.append(cur)
    toks = []
    for t in out:
        t = t.rstrip(".,:;")
        if t.count("{") != t.count("}"):
            t = t.split("{")[0]
        if t:
            toks.append(t)
    return toks


def check_links(rel, text, bad):
    here = os.path.dirname(rel)
    for n, line in enumerate(text.splitlines(), 1):
        for m in LINK.finditer(line):
            target = m.group(1).split("#")[0]
            if not target or re.match(r"^[a-z][a-z0-9+.-]*:", target):
                continue  # same-page fragment, http:, mailto:...
            target = target.strip("<>")
            path = os.path.normpath(os.path.join(here, target))
            if path.startswith(".."):
                bad.append("%s:%d: link %s leaves the repository" % (rel, n, target))
            elif not os.path.exists(os.path.join(ROOT, path)):
                bad.append("%s:%d: link %s: no %s" % (rel, n, target, path))


def check_paths(rel, text, bad):
    history = rel.startswith("experiments/")
    for n, line in enumerate(text.splitlines(), 1):
        for m in PATH.finditer(line):
            if history and m.group(1).startswith("models/"):
                continue
            if line[m.end():m.end() + 1] == "$":
                continue  # a name built by the shell (models/gaze-$1...)
            for token in split_tokens(m.group(1)):
                for p in expand(token):
                    p = p.rstrip("/") or p
                    # A benchmark program is named by its source (the
                    # binary lives in the build tree).
                    if not exists(p) and not exists(p + ".c"):
                        bad.append("%s:%d: names %s, which does not exist" % (rel, n, p))


def scan():
    bad = []
    files = tracked_files()
    for rel in files:
        if not is_text(rel) or rel == "tests/docs/test_doc_links.py":
            continue
        try:
            with open(os.path.join(ROOT, rel), encoding="utf-8") as f:
                text = f.read()
        except (UnicodeDecodeError, OSError):
            continue
        if rel.endswith(".md"):
            check_links(rel, text, bad)
        check_paths(rel, text, bad)
    return files, bad


def self_test():
    import tempfile
    global ROOT
    with tempfile.TemporaryDirectory() as d:
        ROOT = d
        files = {
            "docs/a.md": "[ok](b.md) [ok](../bench/x.c#sec) [bad](c.md) ![bad](../pic.png)\n"
                         "see bench/x.c and experiments/{r1,r2}.md, experiments/r*.md.\n"
                         "[web](https://example.org/a.md) [top](#a) [out](../../etc)\n",
            "docs/b.md": "names docs/gone.md and bench/run, $ROOT/bench/nope.sh, models/m-$1.st\n",
            "bench/x.c": "/* experiments/r3.md; --model models/m.st,models/n.st */\n",
            "experiments/r1.md": "models/old.st, docs/gone2.md", "experiments/r2.md": "",
            "models/m.st": "",
        }
        for rel, text in files.items():
            os.makedirs(os.path.join(d, os.path.dirname(rel)), exist_ok=True)
            with open(os.path.join(d, rel), "w") as f:
                f.write(text)
        _, bad = scan()
    want = ["docs/a.md:1: link c.md: no docs/c.md",
            "docs/a.md:1: link ../pic.png: no pic.png",
            "docs/a.md:3: link ../../etc leaves the repository",
            "docs/b.md:1: names docs/gone.md, which does not exist",
            "docs/b.md:1: names bench/run, which does not exist",
            "experiments/r1.md:1: names docs/gone2.md, which does not exist",
            "bench/x.c:1: names experiments/r3.md, which does not exist",
            "bench/x.c:1: names models/n.st, which does not exist"]
    if sorted(bad) != sorted(want):
        print("self-test: found\n  %s\nwanted\n  %s" % ("\n  ".join(sorted(bad)),
                                                      "\n  ".join(sorted(want))))
        return 1
    print("test_doc_links --self-test: the %d known broken references, no others" % len(want))
    return 0


def main():
    global ROOT
    if len(sys.argv) > 1 and sys.argv[1] == "--self-test":
        return self_test()
    if len(sys.argv) > 1:
        ROOT = os.path.abspath(sys.argv[1])
    files, bad = scan()
    for b in bad:
        print(b)
    print("test_doc_links: %d files, %d broken references" % (len(files), len(bad)))
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
