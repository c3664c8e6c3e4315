"""A subject from several images over the real socket (FitRequest.
more_images; docs/subjects.md): a tiny real model, three normalized
faces. One image answers as before (the same key and bytes as a FIT
without more_images); three images fit one subject whose key covers all
of them in order, say what the fit made of each (image_results), are
cached, render by key, and fine-tune one set of tuned tensors; bad
inputs (17 images, images of different sizes, mixed kinds, a bad label,
a face the gate refuses) are refused naming the image, and the daemon
still answers. `gazesplat client fit --image A,B,C` asks the same.
usage: test_daemon_multi.py GAZESPLATD GAZESPLAT_CLI WORKDIR"""
import os
import subprocess
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.join(HERE, "..", "..", "clients", "python"))
from daemon_util import Checks, Daemon  # noqa: E402
from model_fixture import faces, tiny_model  # noqa: E402
from client_checks import finish, refused, start_ready  # noqa: E402
import gazesplat_client as gc  # noqa: E402

FAST = 6  # fit iterations


def main():
    daemon, cli, work = (os.path.abspath(a) for a in sys.argv[1:4])
    os.makedirs(work, exist_ok=True)
    t = Checks()
    model = tiny_model(cli, work, seed=1)
    imgs = faces(cli, work, 128, 3)
    d, addr = start_ready(t, Daemon, daemon, ["--model", model, "--set", "photo_input=no"])
    try:
        with gc.Client(addr) as c:
            one = c.fit(imgs[0], gaze_deg=(5, 0), max_iters=FAST)
            again = c.fit(imgs[0], gaze_deg=(5, 0), max_iters=FAST, more_images=[])
            t.check(again.subject_key == one.subject_key and again.cached,
                    "no more_images: the one-image key, cached")
            t.check(len(one.image_results) == 0, "one image: no image_results")

            more = [(imgs[1], None, (3, -4)), imgs[2]]
            r = c.fit(imgs[0], gaze_deg=(5, 0), max_iters=FAST, more_images=more)
            t.check(r.subject_key != one.subject_key and not r.cached and r.iters >= 1,
                    "three images: another subject, fitted (%d iterations)" % r.iters)
            t.check(len(r.image_results) == 3, "image_results: %d" % len(r.image_results))
            if len(r.image_results) == 3:
                ir = r.image_results
                t.check(abs(ir[0].gaze.pitch_deg - 5) < 1e-9 and abs(ir[0].gaze.yaw_deg) < 1e-9,
                        "image 0 keeps its gaze label: %s" % ir[0].gaze)
                t.check(abs(ir[1].head.pitch_deg - 3) < 1e-6 and abs(ir[1].head.yaw_deg + 4) < 1e-6,
                        "image 1 keeps its head label: %s" % ir[1].head)
                t.check(ir[0].psnr == r.psnr and ir[0].ssim == r.ssim,
                        "the subject is image 0's: PSNR %.3f vs %.3f" % (ir[0].psnr, r.psnr))
                t.check(all(x.psnr > 5 for x in ir), "every image fitted: %s" % [x.psnr for x in ir])
            r2 = c.fit(imgs[0], gaze_deg=(5, 0), max_iters=FAST, more_images=more)
            t.check(r2.cached and r2.subject_key == r.subject_key and len(r2.image_results) == 0,
                    "the same three images: cached")
            swapped = c.fit(imgs[0], gaze_deg=(5, 0), max_iters=FAST, more_images=more[::-1])
            t.check(swapped.subject_key != r.subject_key, "the key covers the order")
            relab = c.fit(imgs[0], gaze_deg=(5, 0), max_iters=FAST,
                          more_images=[(imgs[1], None, (3, -5)), imgs[2]])
            t.check(relab.subject_key != r.subject_key, "the key covers each image's labels")

            outs = list(c.redirect([(10, -15), (0, 0)], subject=r.subject_key, fmt="raw"))
            t.check(len(outs) == 2 and all(len(o.image.data) == 128 * 128 * 3 for o in outs),
                    "REDIRECT of the multi-image subject by key")
            ft = c.fit(imgs[0], gaze_deg=(5, 0), max_iters=FAST, more_images=more, finetune_steps=3)
            t.check(ft.finetuned and ft.finetune_steps >= 1 and ft.subject_key != r.subject_key,
                    "fine-tuned over the three pairs: %d steps" % ft.finetune_steps)
            outs = list(c.redirect([(10, -15)], subject=ft.subject_key, fmt="raw"))
            t.check(len(outs) == 1, "REDIRECT of the fine-tuned multi-image subject")

            # 17 images, past the client's own check: the server refuses them
            big = gc.pb.FitRequest(image=gc.pb.Image(format=gc.pb.FORMAT_PNG, data=imgs[0]))
            for _ in range(16):
                big.more_images.add().image.CopyFrom(gc.pb.Image(format=gc.pb.FORMAT_PNG, data=imgs[1]))
            refused(t, lambda: c.call(gc.pb.FRAME_FIT, big, gc.pb.FRAME_FIT_OK),
                    gc.pb.ERR_INVALID_ARGUMENT, "17 images", "too many images")
            small = np.zeros((64, 64, 3), np.uint8)
            refused(t, lambda: c.fit(imgs[0], max_iters=FAST, more_images=[imgs[1], small]),
                    gc.pb.ERR_INVALID_ARGUMENT, "images of different sizes", "image 2")
            refused(t, lambda: c.fit(imgs[0], max_iters=FAST, more_images=[(imgs[1], (99, 0), None)]),
                    gc.pb.ERR_INVALID_ARGUMENT, "a bad label of image 1", "image 1")
            grey = np.full((128, 128, 3), 128, np.uint8)
            refused(t, lambda: c.fit(imgs[0], max_iters=FAST, more_images=[imgs[1], grey]),
                        gc.pb.ERR_FACE_REFUSED, "a flat image 2", "image 2")
            t.check(len(c.fit(imgs[1], max_iters=FAST).subject_key) == 16, "the daemon still fits")
        paths = []
        for i, im in enumerate(imgs):
            paths.append(os.path.join(work, "multi_face%d.png" % i))
            with open(paths[-1], "wb") as f:
                f.write(im)
        p = subprocess.run([cli, "client", "fit", "--addr", addr, "--image", ",".join(paths),
                            "--gaze", "5,0;-;-", "--head", "-;3,-4;-", "--max-iters", str(FAST)],
                           capture_output=True, text=True)
        t.check(p.returncode == 0 and ("subject %s" % r.subject_key.hex()) in p.stdout
                and "image 2 gaze_deg" not in p.stdout,
                "client fit of three files: the same (cached) subject: %s %s" % (p.stdout, p.stderr))
        p = subprocess.run([cli, "client", "fit", "--addr", addr, "--image", ",".join(paths[::-1]),
                            "--max-iters", str(FAST)], capture_output=True, text=True)
        t.check(p.returncode == 0 and "image 2 gaze_deg" in p.stdout,
                "client fit of three files: each image's result: %s %s" % (p.stdout, p.stderr))
        p = subprocess.run([cli, "client", "fit", "--addr", addr, "--image", ",".join(paths),
                            "--gaze", "5,0;-"], capture_output=True, text=True)
        t.check(p.returncode == 2 and "2 items for 3 images" in p.stderr,
                "client fit: one label item short: %s" % p.stderr)
    finally:
        finish(t, d)
    return t.status()


if __name__ == "__main__":
    sys.exit(main())
