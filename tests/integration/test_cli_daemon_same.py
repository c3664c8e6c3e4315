"""The CLI and the daemon redirect a photo to the same bytes: `gazesplat
redirect --image PHOTO` against `gazesplat client redirect --photo
--paste-back` on a running gazesplatd with the same model, targets and
options, plain, with detail transfer, and fine-tuned with transfer (the
served defaults on both sides: the fit's head distance d_n, the paste-back
mask of gs_face_paste_mask, the fine-tuning rate GS_FINETUNE_LR_SERVED).
Each case starts a fresh daemon, so no earlier request's renders are in
its contexts. usage: test_cli_daemon_same.py GAZESPLATD GAZESPLAT_CLI
WORKDIR PHOTO"""
import filecmp
import os
import shutil
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.join(HERE, "..", "..", "clients", "python"))
from daemon_util import Checks, Daemon  # noqa: E402
from model_fixture import tiny_model  # noqa: E402
from client_checks import finish, start_ready  # noqa: E402

TARGETS = "10,15;-10,-20;0,25"
CASES = (("plain", []), ("transfer", ["--transfer"]),
         ("finetune+transfer", ["--transfer", "--finetune", "3"]))


def main():
    daemon, cli, work = (os.path.abspath(a) for a in sys.argv[1:4])
    photo = os.path.abspath(sys.argv[4])
    os.makedirs(work, exist_ok=True)
    model = tiny_model(cli, work, seed=1)
    t = Checks()
    rc = 0
    for name, extra in CASES:
        out_c = os.path.join(work, "same_cli_" + name.replace("+", "_"))
        out_d = os.path.join(work, "same_daemon_" + name.replace("+", "_"))
        for d in (out_c, out_d):
            shutil.rmtree(d, ignore_errors=True)
        r = subprocess.run([cli, "redirect", "--model", model, "--image", photo, "--gaze-deg",
                            TARGETS, "--iters", "8", "--out", out_c] + extra,
                           capture_output=True, text=True)
        t.check(r.returncode == 0, "%s: gazesplat redirect: %s" % (name, r.stderr[-400:]))
        state = os.path.join(work, "same_state")
        shutil.rmtree(state, ignore_errors=True)
        os.makedirs(state)
        d, addr = start_ready(t, Daemon, daemon, ["--model", model, "--state-dir", state])
        r = subprocess.run([cli, "client", "redirect", "--addr", addr, "--photo", "--paste-back",
                            "--image", photo, "--gaze-deg", TARGETS, "--max-iters", "8",
                            "--out", out_d] + extra, capture_output=True, text=True)
        t.check(r.returncode == 0, "%s: client redirect: %s" % (name, r.stderr[-400:]))
        for k in range(3):
            a = os.path.join(out_c, "%03d.png" % k)
            b = os.path.join(out_d, "target_%03d.png" % k)
            t.check(os.path.exists(a) and os.path.exists(b) and filecmp.cmp(a, b, shallow=False),
                    "%s: target %d: the CLI's %s and the daemon's %s differ" % (name, k, a, b))
        rc |= finish(t, d)
    sys.exit(t.status() or rc)


if __name__ == "__main__":
    main()
