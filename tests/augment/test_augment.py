"""`gazesplat augment` end to end with a tiny real model (trained at test
time, cached in the build tree) and `gazesplat synth` faces.

usage: test_augment.py GAZESPLAT_CLI WORKDIR MODE
  MODE errors  usage and input errors: exit statuses 2 and 1, messages that
               name the file and line or row, nothing done lost (bad labels,
               NaN, HDF5 of the wrong shape or type, an unreadable image, a
               full disk, shard out of range), help, the TTY progress line
  MODE resume  the HDF5 read by h5py (ETH-XGaze names, shapes, dtypes);
               HDF5 in; shards against the whole run; kill -9 at several
               moments and rerun: the same bytes as an uninterrupted run
  MODE addr GAZESPLATD  the same through the daemon (--addr): its renders
               are the in-process renders byte for byte, killed and rerun
               too; an unreachable address
  MODE minq GAZESPLATD  --min-quality X, X between the scores of a --quality
               run: the kept samples are that run's samples scoring >= X
               (and the unscored head changes), byte for byte; dropped.jsonl
               lists exactly the others; the HDF5's shapes; X = 0 drops
               nothing; a bad X is bad usage; the manifest's decisions;
               --threads, kill -9 and resume, a full disk and resume (only
               the sources not done are made again), shards and --merge
               (and its refusal of a missing dropped list), every sample
               dropped (exit 0, HDF5 of 0 rows), and through the daemon:
               the same decisions and bytes, also with --no-transfer; a
               daemon that cannot measure: kept unscored, with a warning"""
import json
import os
import pty
import re
import shutil
import signal
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "integration"))
from model_fixture import tiny_model  # noqa: E402

FAILS = []
COUNT = [0]


def check(cond, what):
    COUNT[0] += 1
    if not cond:
        FAILS.append(what)
        print("CHECK failed:", what, flush=True)
    return cond


def run(*args, env=None):
    e = dict(os.environ)
    e.update(env or {})
    return subprocess.run([str(a) for a in args], capture_output=True, text=True, timeout=300,
                          env=e)


def synth_faces(cli, work, count):
    out = os.path.join(work, "aug_faces%d" % count)
    if not os.path.exists(os.path.join(out, "labels.jsonl")):
        subprocess.run([cli, "synth", "--out", out, "--count", str(count), "--size", "128",
                        "--seed-split", "test", "--identities", str(count), "--no-masks"],
                       check=True, capture_output=True)
    return out


def labels_csv(faces_dir, path, rows=None, header=None):
    """A labels CSV from synth's labels.jsonl (degrees, normalized camera)."""
    deg = 57.29577951308232
    lines = [header or "file,gaze_pitch_deg,gaze_yaw_deg,head_pitch_deg,head_yaw_deg,subject"]
    with open(os.path.join(faces_dir, "labels.jsonl")) as f:
        for ln in f:
            j = json.loads(ln)
            lines.append("%s,%.4f,%.4f,%.4f,%.4f,id%d" % (
                os.path.basename(j["image"]), j["gaze_cam_pitch_rad"] * deg,
                j["gaze_cam_yaw_rad"] * deg, j["head_pitch_rad"] * deg, j["head_yaw_rad"] * deg,
                j["identity_seed"] % 1000))
    if rows:
        lines += rows
    with open(path, "w") as f:
        f.write("\n".join(lines) + "\n")
    return path


def tree_bytes(d):
    """Every file under d except the state directories, as bytes."""
    out = {}
    for root, dirs, files in os.walk(d):
        dirs[:] = [x for x in dirs if not x.startswith(".augment")]
        for n in files:
            p = os.path.join(root, n)
            out[os.path.relpath(p, d)] = open(p, "rb").read()
    return out


def errors(cli, work):
    model = tiny_model(cli, work, seed=1)
    faces = synth_faces(cli, work, 3)
    imgs = os.path.join(faces, "images")
    out = os.path.join(work, "aug_err")
    shutil.rmtree(out, ignore_errors=True)
    base = [cli, "augment", "--model", model, "--input", imgs, "--iters", "5", "--finetune", "0"]
    grid = ["--grid", "-10:10:10,0:0:1"]

    r = run(cli, "help", "augment")
    check(r.returncode == 0 and r.stdout.startswith("usage: gazesplat augment"), "help augment")
    r = run(*base, "--out", out)
    check(r.returncode == 2 and "one of --grid" in r.stderr, "no targets: %d %s" % (r.returncode, r.stderr))
    r = run(*base, "--out", out, *grid, "--shard", "3/3")
    check(r.returncode == 2 and "out of range" in r.stderr, "shard 3/3: %d %s" % (r.returncode, r.stderr))
    r = run(*base, "--out", out, *grid, "--shard", "1/0")
    check(r.returncode == 2, "shard 1/0: %d" % r.returncode)
    r = run(*base, "--out", out, "--gaze-deg", "70,0")
    check(r.returncode == 2 and "range" in r.stderr, "gaze out of range: %s" % r.stderr)
    r = run(*base, "--out", out, "--uniform", "-10,10,-10,10")
    check(r.returncode == 2 and "--per-image" in r.stderr, "uniform without per-image")
    r = run(*base, "--out", out, *grid, "--head-deg", "80,0")
    check(r.returncode == 2 and "range" in r.stderr, "head out of range: %s" % r.stderr)

    # Labels: unknown (mislabelled) column, missing key column, NaN, an
    # unknown file, half a pair, a malformed JSONL line.
    lab = os.path.join(work, "aug_labels_bad.csv")
    labels_csv(faces, lab, header="file,pitch,gaze_yaw_deg,head_pitch_deg,head_yaw_deg,subject")
    r = run(*base, "--out", out, *grid, "--labels", lab)
    check(r.returncode == 1 and lab in r.stderr and "unknown column 'pitch'" in r.stderr,
          "mislabelled column: %s" % r.stderr)
    with open(lab, "w") as f:
        f.write("name,gaze_pitch_deg,gaze_yaw_deg\n00000000.png,1,2\n")
    r = run(*base, "--out", out, *grid, "--labels", lab)
    check(r.returncode == 1 and "unknown column 'name'" in r.stderr, "no file column: %s" % r.stderr)
    with open(lab, "w") as f:
        f.write("file,gaze_pitch_deg,gaze_yaw_deg\n00000000.png,1,2\n00000001.png,nan,2\n")
    r = run(*base, "--out", out, *grid, "--labels", lab)
    check(r.returncode == 1 and lab + " line 3" in r.stderr and "nan" in r.stderr,
          "NaN label: %s" % r.stderr)
    with open(lab, "w") as f:
        f.write("file,gaze_pitch_deg,gaze_yaw_deg\n00000000.png,1,2\nmissing.png,1,2\n")
    r = run(*base, "--out", out, *grid, "--labels", lab)
    check(r.returncode == 1 and "line 3" in r.stderr and "no image 'missing.png'" in r.stderr,
          "unknown file: %s" % r.stderr)
    with open(lab, "w") as f:
        f.write("file,gaze_pitch_deg,gaze_yaw_deg\n00000000.png,1,\n")
    r = run(*base, "--out", out, *grid, "--labels", lab)
    check(r.returncode == 1 and "line 2" in r.stderr and "without" in r.stderr,
          "half a pair: %s" % r.stderr)
    labj = os.path.join(work, "aug_labels_bad.jsonl")
    with open(labj, "w") as f:
        f.write('{"file": "00000000.png", "gaze_pitch_deg": 1, "gaze_yaw_deg": 2}\n'
                '{"file": "00000001.png", "gaze_pitch_deg": [1]}\n')
    r = run(*base, "--out", out, *grid, "--labels", labj)
    check(r.returncode == 1 and labj + ": line 2" in r.stderr, "bad JSONL: %s" % r.stderr)
    check(not os.path.exists(out), "nothing written on label errors")

    # HDF5 of the wrong shape, dtype, label shape; NaN in a label.
    import h5py
    import numpy as np
    h5 = os.path.join(work, "aug_bad.h5")
    cases = [
        ({"face_patch": np.zeros((2, 128, 128), np.uint8)}, "rank 3"),
        ({"face_patch": np.zeros((2, 128, 128, 4), np.uint8)}, "not 3 channels"),
        ({"face_patch": np.zeros((2, 128, 128, 3), np.float32)}, "not uint8"),
        ({"face_patch": np.zeros((2, 128, 128, 3), np.uint8),
          "face_gaze": np.zeros((3, 2), np.float32)}, "face_gaze has shape"),
        ({"face_patch": np.zeros((2, 128, 128, 3), np.uint8),
          "face_head_pose": np.zeros((2, 2), np.int32)}, "face_head_pose is not of a float type"),
        ({"face_gaze": np.zeros((2, 2), np.float32)}, "no dataset face_patch"),
        ({"face_patch": np.zeros((2, 128, 128, 3), np.uint8),
          "face_gaze": np.array([[0, 0], [np.nan, 0]], np.float32)}, "face_gaze row 1"),
    ]
    for data, want in cases:
        with h5py.File(h5, "w") as f:
            for k, v in data.items():
                f[k] = v
        r = run(cli, "augment", "--model", model, "--input", h5, "--out", out, *grid)
        check(r.returncode == 1 and want in r.stderr and h5 in r.stderr,
              "HDF5 %s: %d %s" % (want, r.returncode, r.stderr))
    with open(h5, "wb") as f:
        f.write(b"not hdf5 at all")
    r = run(cli, "augment", "--model", model, "--input", h5, "--out", out, *grid)
    check(r.returncode == 1 and "cannot open as HDF5" in r.stderr, "not HDF5: %s" % r.stderr)
    check(not os.path.exists(out), "nothing written on HDF5 errors")

    # An unreadable image after two good ones: exit 1 naming it, the two
    # kept; fixed, the rerun does only the rest.
    src = os.path.join(work, "aug_src_bad")
    shutil.rmtree(src, ignore_errors=True)
    shutil.copytree(imgs, src)
    bad = os.path.join(src, "00000002.png")
    good = open(bad, "rb").read()
    with open(bad, "wb") as f:
        f.write(b"\x89PNG\r\n\x1a\n" + b"\0" * 40)
    r = run(cli, "augment", "--model", model, "--input", src, "--out", out, *grid, "--iters", "5", "--finetune", "0")
    check(r.returncode == 1 and bad in r.stderr, "bad image: %d %s" % (r.returncode, r.stderr))
    man = open(os.path.join(out, ".augment", "manifest")).read().splitlines()
    check(man[1:] == ["done 0", "done 1"], "manifest keeps the good two: %s" % man)
    with open(bad, "wb") as f:
        f.write(good)
    r = run(cli, "augment", "--model", model, "--input", src, "--out", out, *grid, "--iters", "5", "--finetune", "0")
    check(r.returncode == 0 and "resuming: 2 of 3" in r.stderr and "1/3" not in r.stderr,
          "rerun after the fix: %d %s" % (r.returncode, r.stderr))
    r = run(cli, "augment", "--model", model, "--input", src, "--out", out, *grid, "--iters", "5", "--finetune", "0")
    check(r.returncode == 0 and "already complete" in r.stdout, "third run: %s" % r.stdout)
    r = run(cli, "augment", "--model", model, "--input", src, "--out", out, *grid, "--iters", "6", "--finetune", "0")
    check(r.returncode == 1 and "another augment run" in r.stderr, "other options: %s" % r.stderr)
    ref = tree_bytes(out)

    # A full disk: the hook, then (when this host lets us mount one) a real
    # tiny tmpfs. Exit 1 naming the file; resumed, the same bytes.
    out2 = os.path.join(work, "aug_enospc")
    shutil.rmtree(out2, ignore_errors=True)
    args = [cli, "augment", "--model", model, "--input", src, "--out", out2, *grid, "--iters", "5",
            "--finetune", "0"]
    r = run(*args, env={"GAZESPLAT_AUGMENT_ENOSPC_AFTER": "8"})
    check(r.returncode == 1 and "No space left on device" in r.stderr and out2 in r.stderr,
          "ENOSPC hook: %d %s" % (r.returncode, r.stderr))
    # A torn last manifest line (killed mid-append) is cut; a listed source
    # whose parts are gone is made again.
    man_path = os.path.join(out2, ".augment", "manifest")
    man = open(man_path).read()
    check(man.endswith("done 0\n"), "ENOSPC: source 0 done: %r" % man)
    with open(man_path, "a") as f:
        f.write("done 1")
    os.unlink(os.path.join(out2, ".augment", "00000000.jsonl"))
    r = run(*args)
    check(r.returncode == 0 and "resuming" not in r.stderr and tree_bytes(out2) == ref,
          "after ENOSPC, a torn line and a lost part: the same bytes (%s)" % r.stderr)
    mnt = os.path.join(work, "aug_tmpfs")
    os.makedirs(mnt, exist_ok=True)
    if subprocess.run(["mount", "-t", "tmpfs", "-o", "size=250k", "tmpfs", mnt],
                      capture_output=True).returncode == 0:
        try:
            r = run(cli, "augment", "--model", model, "--input", src, "--out",
                    os.path.join(mnt, "o"), *grid, "--iters", "5", "--finetune", "0")
            check(r.returncode == 1 and "No space left on device" in r.stderr,
                  "tmpfs full: %d %s" % (r.returncode, r.stderr))
            man = open(os.path.join(mnt, "o", ".augment", "manifest")).read().splitlines()
            check(len(man) >= 2 and man[1] == "done 0", "tmpfs: done sources kept: %s" % man)
        finally:
            subprocess.run(["umount", mnt])
    else:
        print("no tmpfs (not allowed to mount here): the hook alone")

    # A targets file: per-source rows, a bad row named.
    tf = os.path.join(work, "aug_targets.csv")
    with open(tf, "w") as f:
        f.write("file,gaze_pitch_deg,gaze_yaw_deg,head_pitch_deg,head_yaw_deg\n"
                "00000001.png,5,5,,\n00000000.png,-5,10,10,0\n00000001.png,0,-20,,\n")
    to = os.path.join(work, "aug_targets_out")
    shutil.rmtree(to, ignore_errors=True)
    r = run(*base, "--out", to, "--targets", tf, "--format", "png")
    lines = [json.loads(x) for x in open(os.path.join(to, "labels.jsonl"))] if r.returncode == 0 else []
    check([(x["source"], x["index"], x["target_index"], round(x["gaze_head_yaw_rad"] * 57.29578),
            x["head_changed"]) for x in lines] ==
          [("00000000.png", 0, 0, 10, True), ("00000001.png", 1, 0, 5, False),
           ("00000001.png", 2, 1, -20, False)], "targets file: %s %s" % (r.stderr, lines))
    with open(tf, "a") as f:
        f.write("00000002.png,60,0,,\n")
    r = run(*base, "--out", os.path.join(work, "aug_targets_bad"), "--targets", tf)
    check(r.returncode == 1 and tf + " line 5" in r.stderr and "range" in r.stderr,
          "targets file out of range: %s" % r.stderr)

    # A photo: its normalized face and fit are redirect's, so augment's
    # patch is redirect's --out-norm crop byte for byte.
    photo = os.path.join(HERE, "..", "..", "samples", "astronaut.jpg")
    if os.path.exists(photo):
        pd = os.path.join(work, "aug_photo")
        shutil.rmtree(pd, ignore_errors=True)
        os.makedirs(pd)
        shutil.copy(photo, pd)
        po, ro = os.path.join(work, "aug_photo_out"), os.path.join(work, "aug_photo_redirect")
        for d in (po, ro):
            shutil.rmtree(d, ignore_errors=True)
        r = run(cli, "augment", "--model", model, "--input", pd, "--out", po, "--gaze-deg", "10,-20",
                "--iters", "6", "--finetune", "0", "--no-transfer", "--format", "png")
        r2 = run(cli, "redirect", "--model", model, "--image", photo, "--gaze-deg", "10,-20",
                 "--iters", "6", "--out", ro, "--out-norm")
        ok = r.returncode == 0 and r2.returncode == 0
        check(ok and open(os.path.join(po, "images", "00000000.png"), "rb").read() ==
              open(os.path.join(ro, "norm_000.png"), "rb").read(),
              "photo: augment = redirect's normalized crop (%s %s)" % (r.stderr[-300:], r2.stderr[-300:]))
        line = json.loads(open(os.path.join(po, "labels.jsonl")).readline()) if ok else {}
        check(line.get("source_kind") == "photo", "photo source_kind")

    # The served setting (the defaults: fine-tuning and detail transfer) on
    # one face, twice: the same bytes; fine-tuned, so finetune_psnr is set.
    one = os.path.join(work, "aug_one")
    shutil.rmtree(one, ignore_errors=True)
    os.makedirs(one)
    shutil.copy(os.path.join(imgs, "00000000.png"), one)
    outs = []
    for k in range(2):
        o = os.path.join(work, "aug_served%d" % k)
        shutil.rmtree(o, ignore_errors=True)
        r = run(cli, "augment", "--model", model, "--input", one, "--out", o, "--gaze-deg", "0,0;10,-10",
                "--iters", "8", "--finetune", "4")
        check(r.returncode == 0, "served setting: %s" % r.stderr)
        outs.append(tree_bytes(o))
    check(outs[0] == outs[1] and len(outs[0]) == 4, "served setting: the same bytes twice")
    ln = json.loads(outs[0]["labels.jsonl"].decode().splitlines()[0])
    check(ln["finetune_psnr"] is not None and ln["fit_psnr"] is not None, "finetune_psnr %s" % ln)

    # Progress: a terminal gets the \r line with an ETA; a pipe gets none.
    out3 = os.path.join(work, "aug_tty")
    shutil.rmtree(out3, ignore_errors=True)
    pid, fd = pty.fork()
    if pid == 0:
        os.dup2(os.open(os.devnull, os.O_WRONLY), 1)
        os.execv(cli, [cli, "augment", "--model", model, "--input", imgs, "--out", out3, *grid,
                       "--iters", "3", "--finetune", "0", "--format", "png"])
    buf = b""
    while True:
        try:
            chunk = os.read(fd, 4096)
        except OSError:
            break
        if not chunk:
            break
        buf += chunk
    _, st = os.waitpid(pid, 0)
    check(os.WEXITSTATUS(st) == 0 and b"\r" in buf and b"ETA" in buf, "tty progress: %r" % buf[:200])
    check(b"\r" not in r.stderr.encode() and "\r" not in run(*args).stderr, "no \\r to a pipe")


def resume(cli, work):
    import h5py
    import numpy as np
    from PIL import Image
    model = tiny_model(cli, work, seed=1)
    faces = synth_faces(cli, work, 6)
    imgs = os.path.join(faces, "images")
    lab = labels_csv(faces, os.path.join(work, "aug_labels.csv"))
    common = ["--model", model, "--input", imgs, "--labels", lab, "--uniform", "-20,20,-30,30",
              "--per-image", "3", "--head-uniform", "-10,10,-15,15", "--iters", "12", "--seed", "7",
              "--finetune", "0"]
    ref_dir = os.path.join(work, "aug_ref")
    shutil.rmtree(ref_dir, ignore_errors=True)
    t0 = time.time()
    r = run(cli, "augment", *common, "--out", ref_dir)
    full_s = time.time() - t0
    check(r.returncode == 0 and "18 images from 6 sources" in r.stdout, "reference: %s %s" % (r.stdout, r.stderr))
    ref = tree_bytes(ref_dir)
    check(sorted(ref) == sorted(["augment.h5", "labels.jsonl"] + ["images/%08d.png" % i for i in range(18)]),
          "files: %s" % sorted(ref))

    # The HDF5 as ETH-XGaze's tools read it; rows match labels.jsonl.
    with h5py.File(os.path.join(ref_dir, "augment.h5"), "r") as f:
        check(sorted(f.keys()) == ["face_gaze", "face_head_pose", "face_patch"], "keys %s" % list(f))
        check(f["face_patch"].shape == (18, 128, 128, 3) and f["face_patch"].dtype == np.uint8,
              "face_patch %s %s" % (f["face_patch"].shape, f["face_patch"].dtype))
        for k in ("face_gaze", "face_head_pose"):
            check(f[k].shape == (18, 2) and f[k].dtype == np.float32, "%s %s %s" % (k, f[k].shape, f[k].dtype))
        gaze, head, patch = f["face_gaze"][:], f["face_head_pose"][:], f["face_patch"][:]
    lines = [json.loads(x) for x in open(os.path.join(ref_dir, "labels.jsonl"))]
    check(len(lines) == 18 and [x["h5_row"] for x in lines] == list(range(18)), "h5_row")
    check(all(abs(gaze[i, 0] - x["gaze_cam_pitch_rad"]) < 1e-6 and abs(gaze[i, 1] - x["gaze_cam_yaw_rad"]) < 1e-6
              and abs(head[i, 0] - x["head_pitch_rad"]) < 1e-6 for i, x in enumerate(lines)),
          "face_gaze = gaze_cam, face_head_pose = head angles")
    check(all(x["subject"] and x["subject"].startswith("id") and x["quality"] is None
              and x["source_gaze_cam_pitch_rad"] is not None and x["head_changed"] for x in lines),
          "subject, quality null, source labels, head changed")
    check(all(abs(x["gaze_head_pitch_rad"]) <= 20 / 57.29 and abs(x["gaze_head_yaw_rad"]) <= 30 / 57.29
              for x in lines), "targets inside --uniform")
    png = np.asarray(Image.open(os.path.join(ref_dir, "images", "00000004.png")).convert("RGB"))
    check(np.array_equal(png[..., ::-1], patch[4]), "face_patch is BGR of the PNG")

    # Shards: the union of 0/2 and 1/2 is the whole run, line for line.
    sh = os.path.join(work, "aug_shards")
    shutil.rmtree(sh, ignore_errors=True)
    for i in range(2):
        r = run(cli, "augment", *common, "--out", sh, "--shard", "%d/2" % i)
        check(r.returncode == 0, "shard %d: %s" % (i, r.stderr))
    got = {}
    for i in range(2):
        for ln in open(os.path.join(sh, "labels-%d-of-2.jsonl" % i)):
            j = json.loads(ln)
            j.pop("h5_row")
            got[j["index"]] = j
    want = {}
    for x in lines:
        x = dict(x)
        x.pop("h5_row")
        want[x["index"]] = x
    check(got == want, "shards give the whole run's samples")
    check(all(open(os.path.join(sh, "images", n), "rb").read() == ref["images/" + n]
              for n in os.listdir(os.path.join(sh, "images"))), "shard images = whole run's")

    # HDF5 in, as ETH-XGaze writes it (BGR patches, labels in radians): the
    # same faces as a folder give the same renders, so the channels were
    # read right; its labels become the sources'.
    names = sorted(os.listdir(imgs))
    rgb = np.stack([np.asarray(Image.open(os.path.join(imgs, n)).convert("RGB")) for n in names])
    syn = [json.loads(x) for x in open(os.path.join(faces, "labels.jsonl"))]
    fh5 = os.path.join(work, "aug_faces.h5")
    with h5py.File(fh5, "w") as f:
        f["face_patch"] = rgb[..., ::-1]
        f["face_gaze"] = np.array([[x["gaze_cam_pitch_rad"], x["gaze_cam_yaw_rad"]] for x in syn], np.float32)
        f["face_head_pose"] = np.array([[x["head_pitch_rad"], x["head_yaw_rad"]] for x in syn], np.float32)
    plain = ["--gaze-deg", "0,0;10,-10", "--iters", "12", "--finetune", "0", "--no-transfer"]
    h5o, dro = os.path.join(work, "aug_h5in"), os.path.join(work, "aug_dirin")
    for d in (h5o, dro):
        shutil.rmtree(d, ignore_errors=True)
    r = run(cli, "augment", "--model", model, "--input", fh5, "--out", h5o, *plain, "--format", "h5")
    check(r.returncode == 0, "HDF5 input: %s" % r.stderr)
    r = run(cli, "augment", "--model", model, "--input", imgs, "--out", dro, *plain, "--format", "png")
    check(r.returncode == 0, "folder input: %s" % r.stderr)
    with h5py.File(os.path.join(h5o, "augment.h5"), "r") as f:
        hp = f["face_patch"][:]
    pngs = np.stack([np.asarray(Image.open(os.path.join(dro, "images", "%08d.png" % i)).convert("RGB"))
                     for i in range(12)])
    check(hp.shape == (12, 128, 128, 3) and np.array_equal(hp[..., ::-1], pngs),
          "HDF5 (BGR) in = folder in, render for render")
    l2 = [json.loads(x) for x in open(os.path.join(h5o, "labels.jsonl"))]
    check(len(l2) == 12 and l2[5]["source_row"] == 2 and l2[5]["source"] == "aug_faces.h5"
          and abs(l2[5]["source_gaze_cam_pitch_rad"] - syn[2]["gaze_cam_pitch_rad"]) < 1e-6
          and abs(l2[5]["source_head_yaw_rad"] - syn[2]["head_yaw_rad"]) < 1e-6
          and l2[5]["subject"] == "aug_faces" and l2[5]["source_kind"] == "hdf5",
          "HDF5 sources: %s" % (l2[5] if len(l2) > 5 else None))

    # kill -9 at several moments, rerun each time: the same bytes.
    kd = os.path.join(work, "aug_killed")
    shutil.rmtree(kd, ignore_errors=True)
    kills = 0
    # Fractions of the uninterrupted run's time from each start: early
    # (model load, first fit), mid-source, and late (assembly) kills.
    fracs = [0.02, 0.15, 0.3, 0.1, 0.45, 0.2, 0.6, 0.05, 0.8, 0.95]
    for k in range(40):
        p = subprocess.Popen([cli, "augment", *common, "--out", kd], stdout=subprocess.DEVNULL,
                             stderr=subprocess.DEVNULL)
        d = fracs[k % len(fracs)] * max(full_s, 0.5)
        try:
            p.wait(timeout=d)
        except subprocess.TimeoutExpired:
            p.send_signal(signal.SIGKILL)
            p.wait()
            kills += 1
            continue
        break
    check(p.returncode == 0, "finished after %d kills: rc %s" % (kills, p.returncode))
    check(kills >= 2, "killed %d times" % kills)
    r = run(cli, "augment", *common, "--out", kd)
    check(r.returncode == 0, "rerun after finishing")
    got = tree_bytes(kd)
    check(got == ref, "killed run's bytes = uninterrupted run's (%s)" %
          [n for n in set(got) | set(ref) if got.get(n) != ref.get(n)][:5])
    check(not [n for n in os.listdir(kd) if n.endswith(".tmp")], "no .tmp left")
    print("killed %d times; uninterrupted run %.1f s" % (kills, full_s))


def addr(cli, work):
    from daemon_util import Daemon
    daemon = os.path.abspath(sys.argv[4])
    model = tiny_model(cli, work, seed=1)
    faces = synth_faces(cli, work, 3)
    imgs = os.path.join(faces, "images")
    # The served setting, small: fine-tuning, transfer (the kept input), a
    # head change.
    opts = ["--input", imgs, "--gaze-deg", "0,0;10,-10", "--head-deg", "0,0;5,10", "--iters", "10",
            "--finetune", "3"]
    local = os.path.join(work, "aug_local")
    shutil.rmtree(local, ignore_errors=True)
    r = run(cli, "augment", "--model", model, *opts, "--out", local)
    check(r.returncode == 0, "in process: %s" % r.stderr)
    ref = tree_bytes(local)
    r = run(cli, "augment", "--addr", os.path.join(work, "no-such.sock"), *opts, "--out",
            os.path.join(work, "aug_nodaemon"))
    check(r.returncode == 1 and "no-such.sock" in r.stderr, "unreachable: %d %s" % (r.returncode, r.stderr))
    def start(name):
        # A fresh state directory: no subject known from an earlier run.
        state = os.path.join(work, name)
        shutil.rmtree(state, ignore_errors=True)
        os.makedirs(state)
        return Daemon(daemon, ["--model", model, "--state-dir", state, "--set", "photo_input=no"]).start()

    out = os.path.join(work, "aug_remote")
    shutil.rmtree(out, ignore_errors=True)
    d = start("aug_state1")
    try:
        args = [cli, "augment", "--addr", d.sock, *opts, "--out", out]
        t0 = time.time()
        r = run(*args)
        full_s = time.time() - t0
        check(r.returncode == 0, "--addr: %s" % r.stderr)
    finally:
        d.stop()
    got = tree_bytes(out)
    check(sorted(got) == sorted(ref), "files %s" % sorted(got))
    check(all(got[n] == ref[n] for n in ref if n.startswith("images/")),
          "the daemon's renders = the in-process renders")
    lines = [json.loads(x) for x in got.get("labels.jsonl", b"").decode().splitlines()]
    check(len(lines) == 12 and all(x["head_t_mm"] == [None, None, None] and x["fit_psnr"] > 0
                                   and x["finetune_psnr"] is None for x in lines), "labels over --addr")
    # Killed and rerun through a daemon that starts afresh: the bytes of
    # the uninterrupted run (the server's cache answers the rerun's FITs;
    # nothing in the labels depends on whether it did).
    out2 = os.path.join(work, "aug_remote_killed")
    shutil.rmtree(out2, ignore_errors=True)
    d = start("aug_state2")
    try:
        args = [cli, "augment", "--addr", d.sock, *opts, "--out", out2]
        # The first kill comes at a fraction of the uninterrupted run's
        # time; on a loaded machine a run can end before it, and the round
        # starts again afresh with earlier kills (the test needs one).
        for scale in (1.0, 0.3, 0.1):
            shutil.rmtree(out2, ignore_errors=True)
            rc, kills = kill_until_done(args, full_s, (0.3 * scale, 0.6 * scale, 5.0))
            if kills:
                break
    finally:
        d.stop()
    again = tree_bytes(out2)
    check(rc == 0 and kills >= 1 and again == got, "--addr killed %d times: same bytes (%s)" % (
        kills, [n for n in set(got) | set(again) if got.get(n) != again.get(n)][:4]))


def kill_until_done(args, full_s, fracs):
    """Runs args, killing it (SIGKILL) after each fraction of full_s in
    turn, until a run finishes; returns (its exit status, kills)."""
    kills = 0
    for k in range(40):
        p = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            p.wait(timeout=fracs[k % len(fracs)] * max(full_s, 0.5))
        except subprocess.TimeoutExpired:
            p.send_signal(signal.SIGKILL)
            p.wait()
            kills += 1
            continue
        return p.returncode, kills
    return None, kills


def no_row(line):
    """A label line without its h5_row (the only field that moves when
    samples before it are dropped)."""
    return re.sub(r',"h5_row":[0-9]+', "", line)


def pick_threshold(scores):
    """A threshold midway between two distinct (rounded) scores, as even a
    split as there is, with a gap wide enough that rounding to 4 places
    cannot move a score across it; None when the scores do not spread."""
    d = sorted(set(scores))
    best = None
    for a, b in zip(d, d[1:]):
        if b - a < 0.002:
            continue
        split = min(sum(x < b for x in scores), sum(x >= b for x in scores))
        if best is None or split > best[0]:
            best = (split, round((a + b) / 2, 6))
    return best[1] if best else None


def h5_arrays(path):
    import h5py
    with h5py.File(path, "r") as f:
        return {k: f[k][:] for k in ("face_patch", "face_gaze", "face_head_pose")}


def minq_check_kept(ref, got, x, what):
    """got (a --min-quality x run's tree) against ref (the --quality run's):
    the kept samples, their labels, images and HDF5 rows, and the list of
    the dropped. Returns the expected decisions by index."""
    import numpy as np
    ref_lines = ref["labels.jsonl"].decode().splitlines()
    refs = [json.loads(x_) for x_ in ref_lines]
    keep = [q["quality"] is None or q["quality"]["score"] >= x for q in refs]
    got_lines = got.get("labels.jsonl", b"").decode().splitlines()
    want = [no_row(ln) for ln, k in zip(ref_lines, keep) if k]
    check([no_row(ln) for ln in got_lines] == want and len(want) > 0,
          "%s: labels = the --quality run's kept lines (%d vs %d lines)" % (what, len(got_lines), len(want)))
    check([json.loads(ln)["h5_row"] for ln in got_lines] == list(range(len(want))),
          "%s: h5_row 0..kept-1" % what)
    imgs = sorted(n for n in got if n.startswith("images/"))
    want_imgs = sorted(q["image"] for q, k in zip(refs, keep) if k)
    check(imgs == want_imgs and all(got[n] == ref[n] for n in imgs),
          "%s: the kept images, byte for byte (%d vs %d)" % (what, len(imgs), len(want_imgs)))
    dropped = [json.loads(ln) for ln in got.get("dropped.jsonl", b"").decode().splitlines()]
    gone = [q for q, k in zip(refs, keep) if not k]
    check([d["index"] for d in dropped] == [q["index"] for q in gone] and len(gone) > 0,
          "%s: dropped.jsonl lists exactly the samples under %g (%s vs %s)" % (
              what, x, [d["index"] for d in dropped], [q["index"] for q in gone]))
    check(all(d["source"] == q["source"] and d["subject"] == q["subject"] and
              d["source_index"] == q["source_index"] and d["target_index"] == q["target_index"] and
              d["gaze_head_pitch_rad"] == q["gaze_head_pitch_rad"] and
              d["gaze_head_yaw_rad"] == q["gaze_head_yaw_rad"] and d["score"] < x and
              abs(d["score"] - q["quality"]["score"]) <= 5e-5 and
              d["reason"] == q["quality"]["reason"] and d["quality"] == q["quality"]
              for d, q in zip(dropped, gone)), "%s: dropped.jsonl's fields" % what)
    path = got.get("augment.h5")
    if check(path is not None, "%s: augment.h5 written" % what):
        a, b = h5_arrays(path), h5_arrays(ref["augment.h5"])
        rows = [q["h5_row"] for q, k in zip(refs, keep) if k]
        n = len(rows)
        check(a["face_patch"].shape == (n, 128, 128, 3) and a["face_gaze"].shape == (n, 2) and
              a["face_head_pose"].shape == (n, 2), "%s: HDF5 shapes %s" % (
                  what, [a[k].shape for k in sorted(a)]))
        check(all(np.array_equal(a[k], b[k][rows]) for k in a), "%s: HDF5 rows = the kept rows" % what)
    return {q["index"]: ("d" if not k else "u" if q["quality"] is None else "k")
            for q, k in zip(refs, keep)}


def tree_h5(d):
    """tree_bytes, with augment.h5 as its path (read by h5py)."""
    t = tree_bytes(d)
    if "augment.h5" in t:
        t["augment.h5"] = os.path.join(d, "augment.h5")
    return t


def minq(cli, work):
    from daemon_util import Daemon
    daemon = os.path.abspath(sys.argv[4])
    model = tiny_model(cli, work, seed=1)
    faces = synth_faces(cli, work, 6)
    imgs = os.path.join(faces, "images")
    # Per face 4 gaze-only targets (scored) and, last, one head change
    # (unscored: kept whatever the threshold).
    gazes = ["0,0", "15,-20", "-10,25", "20,10"]
    tf = os.path.join(work, "aug_minq_targets.csv")
    with open(tf, "w") as f:
        f.write("file,gaze_pitch_deg,gaze_yaw_deg,head_pitch_deg,head_yaw_deg\n")
        for n in sorted(os.listdir(imgs)):
            for g in gazes:
                f.write("%s,%s,,\n" % (n, g))
            f.write("%s,5,-5,10,15\n" % n)
    opts = ["--input", imgs, "--targets", tf, "--iters", "12", "--finetune", "0"]
    local = ["--model", model] + opts

    bad_out = os.path.join(work, "aug_minq_bad")
    shutil.rmtree(bad_out, ignore_errors=True)
    for bad in ("abc", "1.5", "-0.1", "nan", "inf", "", "0.5x"):
        r = run(cli, "augment", *local, "--out", bad_out, "--min-quality", bad)
        check(r.returncode == 2 and "--min-quality" in r.stderr and "'%s'" % bad in r.stderr,
              "--min-quality %r: exit %d %s" % (bad, r.returncode, r.stderr[:200]))
    check(not os.path.exists(bad_out), "nothing written on a bad --min-quality")

    # The --quality run: its scores give the threshold.
    qd = os.path.join(work, "aug_minq_quality")
    shutil.rmtree(qd, ignore_errors=True)
    t0 = time.time()
    r = run(cli, "augment", *local, "--quality", "--out", qd)
    full_s = time.time() - t0
    if not check(r.returncode == 0, "--quality run: %s" % r.stderr[-300:]):
        return
    ref = tree_h5(qd)
    refs = [json.loads(x) for x in ref["labels.jsonl"].decode().splitlines()]
    check(len(refs) == 30 and all((x["quality"] is None) == x["head_changed"] for x in refs),
          "--quality: gaze-only samples scored, head changes not")
    scores = [x["quality"]["score"] for x in refs if x["quality"]]
    x = pick_threshold(scores)
    if not check(x is not None, "the scores spread: %s" % sorted(scores)):
        return
    n_drop = sum(s_ < x for s_ in scores)
    n_unscored = sum(x_["quality"] is None for x_ in refs)
    n_keep = len(refs) - n_drop
    print("threshold %g: %d of %d scored samples under it, %d unscored; scores %s" % (
        x, n_drop, len(scores), n_unscored, sorted(scores)))

    md = os.path.join(work, "aug_minq")
    shutil.rmtree(md, ignore_errors=True)
    args = [cli, "augment", *local, "--min-quality", str(x), "--out", md]
    r = run(*args)
    check(r.returncode == 0 and ("%d images from 6 sources" % n_keep) in r.stdout and
          ("%d kept (%d of them unscored), %d dropped" % (n_keep, n_unscored, n_drop)) in r.stdout,
          "--min-quality %g: exit %d, last line %s %s" % (x, r.returncode, r.stdout[-300:], r.stderr[-300:]))
    got = tree_h5(md)
    decisions = minq_check_kept(ref, got, x, "--min-quality %g" % x)
    man = open(os.path.join(md, ".augment", "manifest")).read().splitlines()
    want_man = []
    for k in range(6):
        want_man.append("done %d q=%s" % (k, "".join(decisions[5 * k + t] for t in range(5))))
    check(man[1:] == want_man + ["finished"], "the manifest's decisions: %s" % man[1:])
    r = run(*args)
    check(r.returncode == 0 and "already complete: %d images" % n_keep in r.stdout and
          "%d dropped" % n_drop in r.stdout, "finished, run again: %s" % r.stdout)

    # X = 0: nothing dropped, the --quality run's bytes and an empty list.
    zd = os.path.join(work, "aug_minq0")
    shutil.rmtree(zd, ignore_errors=True)
    r = run(cli, "augment", *local, "--min-quality", "0", "--out", zd)
    z = tree_bytes(zd)
    check(r.returncode == 0 and z.pop("dropped.jsonl", None) == b"" and z == tree_bytes(qd),
          "--min-quality 0: the --quality run's bytes (%s)" % r.stderr[-200:])

    # Any --threads, and killed and resumed: the same bytes.
    td = os.path.join(work, "aug_minq_t1")
    shutil.rmtree(td, ignore_errors=True)
    r = run(cli, "augment", *local, "--min-quality", str(x), "--threads", "1", "--out", td)
    check(r.returncode == 0 and tree_bytes(td) == tree_bytes(md), "--threads 1: the same bytes")
    kd = os.path.join(work, "aug_minq_killed")
    # A resumed run has less left, and on a loaded machine it can finish
    # before its kill: the round starts again afresh with earlier kills
    # until two land (as the --addr test does).
    for scale in (1.0, 0.4, 0.15):
        shutil.rmtree(kd, ignore_errors=True)
        rc, kills = kill_until_done(args[:-1] + [kd], full_s,
                                    [f * scale for f in (0.05, 0.3, 0.5, 0.2, 0.7, 0.9)])
        if kills >= 2:
            break
    check(rc == 0 and kills >= 2, "killed %d times, then exit %s" % (kills, rc))
    again = tree_bytes(kd)
    want = tree_bytes(md)
    check(again == want, "killed run's bytes = uninterrupted run's (%s)" %
          [n for n in set(again) | set(want) if again.get(n) != want.get(n)][:5])
    print("--min-quality run killed %d times; --quality run %.1f s" % (kills, full_s))
    # Stopped by a full disk after a few sources: the rerun takes the done
    # sources' decisions from the manifest and makes only the others.
    ed = os.path.join(work, "aug_minq_enospc")
    shutil.rmtree(ed, ignore_errors=True)
    r = run(*args[:-1], ed, env={"GAZESPLAT_AUGMENT_ENOSPC_AFTER": "24"})
    done = [ln for ln in open(os.path.join(ed, ".augment", "manifest")).read().splitlines()
            if ln.startswith("done ")]
    check(r.returncode == 1 and "No space left on device" in r.stderr and 1 <= len(done) < 6,
          "full disk: exit %d, %d sources done" % (r.returncode, len(done)))
    r = run(*args[:-1], ed)
    redone = re.findall(r"^gazesplat augment: \d+/6 ", r.stderr, re.M)
    check(r.returncode == 0 and "resuming: %d of 6 sources done" % len(done) in r.stderr and
          len(redone) == 6 - len(done) and tree_bytes(ed) == want,
          "full disk, rerun: %d sources made again of %d left, the same bytes (%s)" % (
              len(redone), 6 - len(done), r.stderr[-300:]))

    # Shards, merged: the unsharded run's bytes, dropped.jsonl included.
    sh = os.path.join(work, "aug_minq_shards")
    shutil.rmtree(sh, ignore_errors=True)
    for i in range(2):
        r = run(cli, "augment", *local, "--min-quality", str(x), "--out", sh, "--shard", "%d/2" % i)
        check(r.returncode == 0, "shard %d: %s" % (i, r.stderr[-200:]))
    r = run(cli, "augment", "--merge", "2", "--out", sh)
    check(r.returncode == 0 and "%d kept (%d of them unscored), %d dropped" % (n_keep, n_unscored, n_drop)
          in r.stdout, "merge: %s %s" % (r.stdout, r.stderr[-200:]))
    merged = {n: b for n, b in tree_bytes(sh).items() if "-of-" not in n}
    check(merged == want, "merged shards = the unsharded run (%s)" %
          [n for n in set(merged) | set(want) if merged.get(n) != want.get(n)][:5])
    lone = os.path.join(sh, "dropped-1-of-2.jsonl")
    os.rename(lone, lone + ".away")
    r = run(cli, "augment", "--merge", "2", "--out", sh)
    check(r.returncode == 1 and "1 of 2 shards have a dropped list" in r.stderr,
          "merge with one shard's dropped list gone: %d %s" % (r.returncode, r.stderr))
    os.rename(lone + ".away", lone)

    # Every sample dropped: one face whose scores are all under 1, its
    # gaze-only targets alone (the same renders: they come first).
    worst = [k for k in range(6) if all(refs[5 * k + t]["quality"]["score"] < 0.999 for t in range(4))]
    one = os.path.join(work, "aug_minq_one")
    shutil.rmtree(one, ignore_errors=True)
    os.makedirs(one)
    shutil.copy(os.path.join(imgs, refs[5 * (worst or [0])[0]]["source"]), one)
    if check(worst, "a face scoring under 1 everywhere"):
        ad = os.path.join(work, "aug_minq_all")
        shutil.rmtree(ad, ignore_errors=True)
        r = run(cli, "augment", "--model", model, "--input", one, "--gaze-deg", ";".join(gazes),
                "--iters", "12", "--finetune", "0", "--min-quality", "1", "--out", ad)
        t = tree_h5(ad)
        lst = [json.loads(ln) for ln in t.get("dropped.jsonl", b"").decode().splitlines()]
        check(r.returncode == 0 and "every sample was dropped" in r.stderr and
              "0 kept (0 of them unscored), 4 dropped" in r.stdout and t.get("labels.jsonl") == b""
              and not [n for n in t if n.startswith("images/")] and
              [d["target_index"] for d in lst] == [0, 1, 2, 3] and
              all(abs(d["score"] - q["quality"]["score"]) <= 5e-5
                  for q, d in zip(refs[5 * worst[0]:], lst)),
              "every sample dropped: exit %d %s %s" % (r.returncode, r.stdout[-200:], r.stderr[-300:]))
        if "augment.h5" in t:
            a = h5_arrays(t["augment.h5"])
            check(a["face_patch"].shape == (0, 128, 128, 3) and a["face_gaze"].shape == (0, 2),
                  "every sample dropped: an HDF5 of 0 rows %s" % [a[k].shape for k in sorted(a)])

    # Through the daemon (which measures the quality with its landmark
    # model): the same decisions, images, dropped list and HDF5 patches.
    state = os.path.join(work, "aug_minq_state")
    shutil.rmtree(state, ignore_errors=True)
    os.makedirs(state)
    d = Daemon(daemon, ["--model", model, "--state-dir", state]).start()
    rd = os.path.join(work, "aug_minq_remote")
    shutil.rmtree(rd, ignore_errors=True)
    # Without detail transfer (first, so that no subject is cached with
    # its input): the daemon keeps the input all the same to measure
    # against, so the decisions are the in-process ones.
    nt_opts = ["--input", imgs, "--gaze-deg", ";".join(gazes), "--iters", "12", "--finetune", "0",
               "--no-transfer", "--min-quality", str(x)]
    nt_local, nt_remote = os.path.join(work, "aug_minq_nt"), os.path.join(work, "aug_minq_nt_remote")
    for o in (nt_local, nt_remote):
        shutil.rmtree(o, ignore_errors=True)
    r = run(cli, "augment", "--model", model, *nt_opts, "--out", nt_local)
    check(r.returncode == 0, "--no-transfer in process: %s" % r.stderr[-200:])
    try:
        r2 = run(cli, "augment", "--addr", d.sock, *nt_opts, "--out", nt_remote)
        r = run(cli, "augment", "--addr", d.sock, *opts, "--min-quality", str(x), "--out", rd)
    finally:
        d.stop()
    ntl, ntr = tree_bytes(nt_local), tree_bytes(nt_remote)
    check(r2.returncode == 0 and "warning" not in r2.stderr and ntl.get("dropped.jsonl") and
          ntr.get("dropped.jsonl") == ntl.get("dropped.jsonl") and
          sorted(n for n in ntr if n.startswith("images/")) == sorted(n for n in ntl if n.startswith("images/")),
          "--addr --no-transfer: the in-process decisions (%s)" % r2.stderr[-200:])
    # A daemon that cannot measure (no landmark model: photo_input=no):
    # every gaze-only sample kept unscored, and stderr says so.
    state2 = os.path.join(work, "aug_minq_state2")
    shutil.rmtree(state2, ignore_errors=True)
    os.makedirs(state2)
    d = Daemon(daemon, ["--model", model, "--state-dir", state2, "--set", "photo_input=no"]).start()
    blind = os.path.join(work, "aug_minq_blind")
    shutil.rmtree(blind, ignore_errors=True)
    try:
        r3 = run(cli, "augment", "--addr", d.sock, "--input", one, "--gaze-deg", ";".join(gazes),
                 "--iters", "12", "--finetune", "0", "--min-quality", str(x), "--out", blind)
    finally:
        d.stop()
    check(r3.returncode == 0 and "4 kept (4 of them unscored), 0 dropped" in r3.stdout and
          "warning: 4 gaze-only samples carry no score" in r3.stderr,
          "a daemon without the landmark model: unscored, said so (%s %s)" % (r3.stdout[-200:], r3.stderr[-300:]))
    check(r.returncode == 0 and "%d kept (%d of them unscored), %d dropped" % (n_keep, n_unscored, n_drop)
          in r.stdout and "warning" not in r.stderr, "--addr: %s %s" % (r.stdout[-300:], r.stderr[-300:]))
    rt = tree_h5(rd)
    check(sorted(rt) == sorted(got) and all(rt[n] == got[n] for n in rt if n.startswith("images/"))
          and rt.get("dropped.jsonl") == got["dropped.jsonl"],
          "--addr: the same images and dropped.jsonl, byte for byte")
    rl = [json.loads(ln) for ln in rt.get("labels.jsonl", b"").decode().splitlines()]
    gl = [json.loads(ln) for ln in got["labels.jsonl"].decode().splitlines()]
    check([(q["index"], q["quality"]) for q in rl] == [(q["index"], q["quality"]) for q in gl],
          "--addr: the same kept samples and their quality")
    if "augment.h5" in rt:
        import numpy as np
        check(np.array_equal(h5_arrays(rt["augment.h5"])["face_patch"],
                             h5_arrays(got["augment.h5"])["face_patch"]), "--addr: the same HDF5 patches")


def main():
    cli, work, mode = os.path.abspath(sys.argv[1]), os.path.abspath(sys.argv[2]), sys.argv[3]
    os.makedirs(work, exist_ok=True)
    {"errors": errors, "resume": resume, "addr": addr, "minq": minq}[mode](cli, work)
    print("%d checks, %d failed" % (COUNT[0], len(FAILS)))
    return 1 if FAILS else 0


if __name__ == "__main__":
    sys.exit(main())
