"""gazesplatd fits with the code prior and the code rate its model file
names (config.fit_code_prior and config.fit_code_rate, set with
`gazesplat model --fit-code-prior` and `--fit-code-rate`): a tiny real
model served as trained, with weight 1 and with weight 0, with rate 0.5
and with the library's own 0.12, one daemon each over a real socket.
The weight-1 and rate-0.5 models fit and render otherwise and the daemon
says so at load; the weight-0 and rate-0.12 copies fit and render the
plain model's bytes; the model id follows the file's bytes.
usage: test_daemon_fit_prior.py GAZESPLATD GAZESPLAT_CLI WORKDIR"""
import os
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.join(HERE, "..", "..", "clients", "python"))
from daemon_util import Checks, Daemon  # noqa: E402
from model_fixture import faces, tiny_model  # noqa: E402
from client_checks import finish, start_ready  # noqa: E402
import gazesplat_client as gc  # noqa: E402

FAST = 6  # fit iterations


def serve(t, daemon, model, img):
    """FIT img and render it at one gaze on a daemon serving model:
    (fit PSNR, render bytes, model id, log)."""
    d, addr = start_ready(t, Daemon, daemon, ["--model", model, "--set", "photo_input=no"])
    try:
        with gc.Client(addr) as c:
            r = c.fit(img, max_iters=FAST)
            out = list(c.redirect([(10, -15)], subject=r.subject_key, fmt="raw"))[0].image.data
            mid = c.health().model_id
    finally:
        finish(t, d)
    return r.psnr, out, mid, d.log()


def main():
    daemon, cli, work = (os.path.abspath(a) for a in sys.argv[1:4])
    os.makedirs(work, exist_ok=True)
    t = Checks()
    plain = tiny_model(cli, work, seed=1)
    img = faces(cli, work, 128, 3)[0]
    p1 = os.path.join(work, "prior1.safetensors")
    p0 = os.path.join(work, "prior0.safetensors")
    subprocess.run([cli, "model", "--model", plain, "--fit-code-prior", "1", "--out", p1],
                   check=True, capture_output=True)
    subprocess.run([cli, "model", "--model", p1, "--fit-code-prior", "0", "--out", p0],
                   check=True, capture_output=True)
    psnr_a, out_a, id_a, log_a = serve(t, daemon, plain, img)
    psnr_1, out_1, id_1, log_1 = serve(t, daemon, p1, img)
    psnr_0, out_0, id_0, log_0 = serve(t, daemon, p0, img)
    t.check("code prior" not in log_a, "a model naming no prior: no prior in the log")
    t.check("fits use the model's code prior, weight 1" in log_1, "the weight is logged at load")
    t.check(psnr_1 != psnr_a and out_1 != out_a,
            "weight 1 fits otherwise: PSNR %.4f against %.4f" % (psnr_1, psnr_a))
    t.check(psnr_0 == psnr_a and out_0 == out_a, "weight 0 fits as the plain model: PSNR %.4f against %.4f"
            % (psnr_0, psnr_a))
    r5 = os.path.join(work, "rate05.safetensors")
    r12 = os.path.join(work, "rate012.safetensors")
    subprocess.run([cli, "model", "--model", plain, "--fit-code-rate", "0.5", "--out", r5],
                   check=True, capture_output=True)
    subprocess.run([cli, "model", "--model", plain, "--fit-code-rate", "0.12", "--out", r12],
                   check=True, capture_output=True)
    psnr_r5, out_r5, _, log_r5 = serve(t, daemon, r5, img)
    psnr_r12, out_r12, _, log_r12 = serve(t, daemon, r12, img)
    t.check("code rate" not in log_a, "a model naming no rate: no rate in the log")
    t.check("fits use the model's code rate, 0.5" in log_r5, "the rate is logged at load")
    t.check(psnr_r5 != psnr_a and out_r5 != out_a,
            "rate 0.5 fits otherwise: PSNR %.4f against %.4f" % (psnr_r5, psnr_a))
    t.check(psnr_r12 == psnr_a and out_r12 == out_a,
            "rate 0.12 (the library's) fits as the plain model: PSNR %.4f against %.4f"
            % (psnr_r12, psnr_a))
    # the model id names the file's bytes: the weight-1 file is another
    # model; the weight-0 copy is the plain file itself when that was
    # written with the key (a file from before the key differs in bytes)
    same = open(plain, "rb").read() == open(p0, "rb").read()
    t.check(id_1 != id_a and id_1 != id_0, "the weight-1 file is another model: %s" % [id_a, id_1])
    t.check((id_0 == id_a) == same, "the weight-0 copy's id: %s against %s (same bytes: %s)"
            % (id_0, id_a, same))
    return t.status()


if __name__ == "__main__":
    sys.exit(main())
