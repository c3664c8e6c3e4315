"""`gazesplat client` and gazesplatd's command line against the real
daemon with a tiny real model: hello, health, stats, fit, redirect to
files; exit statuses (0 ok, 1 server error, 2 usage); --check-config and
configuration errors.
usage: test_cli_client.py GAZESPLATD GAZESPLAT_CLI WORKDIR"""
import json
import os
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from daemon_util import Checks, Daemon  # noqa: E402
from model_fixture import faces, tiny_model  # noqa: E402


def run(*args):
    return subprocess.run(list(args), capture_output=True, text=True, timeout=120)


def main():
    daemon, cli, work = (os.path.abspath(a) for a in sys.argv[1:4])
    os.makedirs(work, exist_ok=True)
    t = Checks()
    model = tiny_model(cli, work, seed=1)
    faces(cli, work, 128, 3)
    face = os.path.join(work, "faces128", "images", "00000000.png")

    r = run(daemon, "--check-config", "--set", "workers=3", "--model", model)
    t.check(r.returncode == 0 and "workers = 3" in r.stdout and "model = " + model in r.stdout,
            "--check-config: %d %s" % (r.returncode, r.stdout[:200]))
    r = run(daemon, "--set", "workers=0")
    t.check(r.returncode == 2 and "[1, 64]" in r.stderr, "bad value: %d %s" % (r.returncode, r.stderr))
    r = run(daemon, "--bogus")
    t.check(r.returncode == 2 and "unknown option" in r.stderr, "unknown flag: %d" % r.returncode)
    conf = os.path.join(work, "bad.conf")
    with open(conf, "w") as f:
        f.write("workers = 1\nno_such_key = 3\n")
    r = run(daemon, "-c", conf)
    t.check(r.returncode == 2 and ":2: unknown key" in r.stderr, "bad file: %s" % r.stderr)

    d = Daemon(daemon, ["--model", model, "--set", "photo_input=no"]).start()
    try:
        addr = "--addr=" + d.sock
        for _ in range(200):
            if run(cli, "client", "health", addr).returncode == 0:
                break
            time.sleep(0.05)
        r = run(cli, "client", "health", addr)
        t.check(r.returncode == 0 and "state READY" in r.stdout, "health: %s" % r.stdout)
        r = run(cli, "client", "hello", addr)
        t.check(r.returncode == 0 and "version 1" in r.stdout and "max_targets 64" in r.stdout, "hello")
        r = run(cli, "client", "fit", addr, "--image", face, "--max-iters", "3", "--gaze", "5,-5")
        key = [ln.split()[1] for ln in r.stdout.splitlines() if ln.startswith("subject ")]
        t.check(r.returncode == 0 and len(key) == 1 and "gaze_deg 5.000,-5.000" in r.stdout,
                "fit: %d %s %s" % (r.returncode, r.stdout, r.stderr))
        out = os.path.join(work, "cli_out")
        r = run(cli, "client", "redirect", addr, "--subject", key[0] if key else "0" * 32,
                "--gaze-deg", "0,0;10,-20", "--out", out)
        files = sorted(os.listdir(out)) if os.path.isdir(out) else []
        t.check(r.returncode == 0 and files == ["target_000.png", "target_001.png"],
                "redirect: %d %s %s" % (r.returncode, files, r.stderr))
        r = run(cli, "client", "redirect", addr, "--subject", "ab" * 16, "--gaze-deg", "0,0", "--out", out)
        t.check(r.returncode == 1 and "ERR_UNKNOWN_SUBJECT" in r.stderr, "unknown subject: %s" % r.stderr)
        r = run(cli, "client", "redirect", addr, "--subject", "xyz", "--gaze-deg", "0,0", "--out", out)
        t.check(r.returncode == 2, "bad key is a usage error: %d" % r.returncode)
        # Fine-tuned: the subject says so; a redirect by its key renders.
        r = run(cli, "client", "fit", addr, "--image", face, "--max-iters", "3", "--finetune", "2",
                "--finetune-parts", "face")
        tkey = [ln.split()[1] for ln in r.stdout.splitlines() if ln.startswith("subject ")]
        t.check(r.returncode == 0 and "finetuned yes" in r.stdout and "finetune_steps 2" in r.stdout
                and "finetune_lr 0.004\n" in r.stdout,
                "fit --finetune (the server's rate, 0.004): %d %s %s" % (r.returncode, r.stdout, r.stderr))
        tout = os.path.join(work, "cli_out_tuned")
        r = run(cli, "client", "redirect", addr, "--subject", tkey[0] if tkey else "0" * 32,
                "--gaze-deg", "0,0", "--out", tout)
        t.check(r.returncode == 0 and os.path.exists(os.path.join(tout, "target_000.png")),
                "redirect of a fine-tuned subject: %d %s" % (r.returncode, r.stderr))
        # Detail transfer by key: refused until the fit keeps its input.
        xout = os.path.join(work, "cli_out_transfer")
        r = run(cli, "client", "redirect", addr, "--subject", key[0] if key else "0" * 32,
                "--gaze-deg", "10,-20", "--transfer", "--out", xout)
        t.check(r.returncode == 1 and "ERR_UNKNOWN_SUBJECT" in r.stderr and "keep_image" in r.stderr,
                "transfer without a kept input: %s" % r.stderr)
        r = run(cli, "client", "fit", addr, "--image", face, "--max-iters", "3", "--gaze", "5,-5",
                "--keep-image")
        t.check(r.returncode == 0 and "cached yes" in r.stdout and "image_kept yes" in r.stdout,
                "fit --keep-image: %s %s" % (r.stdout, r.stderr))
        r = run(cli, "client", "redirect", addr, "--subject", key[0] if key else "0" * 32,
                "--gaze-deg", "10,-20", "--transfer", "--out", xout)
        xpng = os.path.join(xout, "target_000.png")
        plain = open(os.path.join(out, "target_001.png"), "rb").read() if files else b""
        t.check(r.returncode == 0 and os.path.exists(xpng) and open(xpng, "rb").read() != plain,
                "redirect --transfer by key: %d %s" % (r.returncode, r.stderr))
        r = run(cli, "client", "fit", addr, "--image", face, "--finetune-parts", "face")
        t.check(r.returncode == 2, "--finetune-parts alone is a usage error: %d" % r.returncode)
        r = run(cli, "client", "fit", addr, "--image", face, "--finetune", "2", "--finetune-parts", "nose")
        t.check(r.returncode == 1 and "ERR_INVALID_ARGUMENT" in r.stderr, "unknown part: %s" % r.stderr)
        r = run(cli, "client", "fit", addr, "--image", face, "--photo")
        t.check(r.returncode == 1 and "ERR_PHOTO_UNSUPPORTED" in r.stderr, "photo: %s" % r.stderr)
        r = run(cli, "client", "stats", addr)
        t.check(r.returncode == 0 and "images_out 4" in r.stdout and "finetunes 1" in r.stdout,
                "stats: %s" % r.stdout[-300:])
        # --finetune-outline: another subject than without it; 0..8, with --finetune only.
        r = run(cli, "client", "fit", addr, "--image", face, "--max-iters", "3", "--finetune", "2",
                "--finetune-parts", "face", "--finetune-outline", "2")
        okey = [ln.split()[1] for ln in r.stdout.splitlines() if ln.startswith("subject ")]
        t.check(r.returncode == 0 and "finetuned yes" in r.stdout and okey and okey != tkey,
                "fit --finetune-outline 2: %d %s %s" % (r.returncode, r.stdout, r.stderr))
        r = run(cli, "client", "fit", addr, "--image", face, "--finetune-outline", "2")
        t.check(r.returncode == 2, "--finetune-outline alone is a usage error: %d" % r.returncode)
        r = run(cli, "client", "fit", addr, "--image", face, "--finetune", "2", "--finetune-outline", "9")
        t.check(r.returncode == 2, "--finetune-outline 9 is a usage error: %d" % r.returncode)
        r = run(cli, "client", "fit", addr, "--image", face, "--finetune", "2", "--finetune-mirror", "2")
        t.check(r.returncode == 2, "--finetune-mirror 2 is a usage error: %d" % r.returncode)
        # --finetune-lr: the rate that ran is reported; another rate, another subject.
        r = run(cli, "client", "fit", addr, "--image", face, "--max-iters", "3", "--finetune", "2",
                "--finetune-parts", "face", "--finetune-lr", "0.0015")
        lkey = [ln.split()[1] for ln in r.stdout.splitlines() if ln.startswith("subject ")]
        t.check(r.returncode == 0 and "finetune_lr 0.0015\n" in r.stdout and lkey and lkey != tkey,
                "fit --finetune-lr 0.0015: %d %s %s" % (r.returncode, r.stdout, r.stderr))
        for bad in ("0", "1.5", "nan", "-1", "x"):
            r = run(cli, "client", "fit", addr, "--image", face, "--finetune", "2", "--finetune-lr", bad)
            t.check(r.returncode == 2 and "--finetune-lr" in r.stderr,
                    "--finetune-lr %s is a usage error: %d %s" % (bad, r.returncode, r.stderr))
        r = run(cli, "client", "fit", addr, "--image", face, "--finetune-lr", "0.01")
        t.check(r.returncode == 2, "--finetune-lr alone is a usage error: %d" % r.returncode)
        # --json: one object per reply (the protocol's field names, keys as hex).
        r = run(cli, "client", "health", addr, "--json")
        h = json.loads(r.stdout) if r.returncode == 0 else {}
        t.check(h.get("state") == "READY" and h.get("image_size") == 128, "health --json: %s" % r.stdout)
        r = run(cli, "client", "stats", addr, "--json")
        st = json.loads(r.stdout) if r.returncode == 0 else {}
        t.check(st.get("images_out", 0) >= 4 and st.get("finetunes", 0) >= 1 and st.get("fits", 0) >= 1,
                "stats --json: %s" % r.stdout[:200])
        r = run(cli, "client", "fit", addr, "--image", face, "--max-iters", "3", "--gaze", "5,-5", "--json")
        fj = json.loads(r.stdout) if r.returncode == 0 else {}
        t.check(key and fj.get("subject_key") == key[0] and fj.get("cached") is True and
                fj.get("gaze") == {"pitch_deg": 5, "yaw_deg": -5}, "fit --json: %s" % r.stdout)
        jout = os.path.join(work, "cli_out_json")
        r = run(cli, "client", "redirect", addr, "--subject", key[0] if key else "0" * 32,
                "--gaze-deg", "0,0;10,-20", "--out", jout, "--json")
        lines = [json.loads(ln) for ln in r.stdout.splitlines()] if r.returncode == 0 else []
        t.check(len(lines) == 3 and [x.get("index") for x in lines[:2]] == [0, 1] and
                lines[1]["target"]["gaze"] == {"pitch_deg": 10, "yaw_deg": -20} and
                os.path.exists(lines[0]["path"]) and lines[2]["done"]["count"] == 2,
                "redirect --json: %s" % r.stdout)
        r = run(cli, "client", "hello", addr, "--json")
        t.check(r.returncode == 0 and json.loads(r.stdout)["limits"]["max_targets"] == 64, "hello --json")
        r = run(cli, "client", "frobnicate", addr)
        t.check(r.returncode == 2, "unknown action: %d" % r.returncode)
        r = run(cli, "client", "health", "--addr=" + os.path.join(work, "nope.sock"))
        t.check(r.returncode == 1 and "connect" in r.stderr, "no server: %s" % r.stderr)
    finally:
        rc = d.stop()
        if t.failures:
            print(d.log()[-3000:])
    t.check(rc == 0, "exit %s" % rc)
    return t.status()


if __name__ == "__main__":
    sys.exit(main())
