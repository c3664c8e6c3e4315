#!/usr/bin/python3
"""PyTorch reference for the model's two Gaussian streams (lib/model/frame.c).

Usage: streams_reference.py DIR

Reads what `test_streams_reference export DIR` wrote into each DIR/<case>/ (a
tiny model's parameters, one frame, a random upstream gradient on each
camera-frame Gaussian tensor), rebuilds both streams in float64 torch from
their written definition (docs/model.md, section Streams), and writes the
camera-frame Gaussians and the gradient of

    L = sum(v_mean * mean) + sum(v_scale * log_scale) + sum(v_quat * quat)
        + sum(v_opac * opacity_logit) + sum(v_feat * feature)

with respect to every stream parameter tensor and every frame input.

Definitions used (not the C code):
  MLP            Linear [out, in] + bias, LeakyReLU 0.01 after hidden layers.
  PE(x), x [n]   [x, sin x, cos x, sin 2x, cos 2x, sin 4x, cos 4x, sin 8x,
                  cos 8x], each term a block of n values.
  face stream    oE = E([f, tau]), oP = P([f, PE(rvec(R))]) (single stream:
                  P([f, PE(rvec(R)), PE(gaze)])); outputs [pos 3 | feat C |
                  log-scale 3 | quat 4 | opacity 1];
                  x = x0 + 4 (l oE.pos + (1-l) oP.pos), s/q/o = s0/q0/o0 +
                  0.2 (l oE + (1-l) oP), c = c0 + oE.feat + oP.feat.
                  rvec(R) is a stop-gradient (docs/model.md, Fitting).
  eye stream     R_e = R_res,e Ry(yaw) Rx(-pitch) (I in the no-rotation
                  ablation); R_res,e the rotation of the unit quaternion
                  normalize((1, 0, 0, 0) + EyeRot_e(PE(gaze)));
                  x = c_e + W_e tau + R_e (x0 - c_e) + 1 o.pos with
                  o = Eye([f, tau, PE(gaze)]) = [pos 3 | feat C | s 1 | a 1];
                  isotropic log-scale s0 + 0.2 o.s, opacity a0 + 0.2 o.a,
                  c = c0 + o.feat, quaternion identity (head frame).
  lids           the last n_lid0 + n_lid1 face Gaussians (eye 0's first),
                  after the face stream: with k bilinear in the eye's knots
                  face.lid_k [2, NV, NU] at the Gaussian's place
                  face.lid_uv (u, v; cell floor(.) clamped to the grid),
                  a = -k pitch and c = c_e + W_e tau, x = c + Rx(a) (x - c)
                  and q = (cos a/2, sin a/2, 0, 0) (x) q.
  camera         x_cam = R x + t, q_cam = q_R (x) q (Hamilton, wxyz, q_R with
                  w > 0); R perturbed on the left, R <- exp([w]) R, w = 0.

Files written per case (float32 .npy): out.mean [n,3], out.scale [n,3],
out.quat [n,4], out.opac [n], out.feat [n,C], grad.<tensor name> for every
stream tensor, grad.code [D], grad.rot [3], grad.trans [3], grad.gaze [2].
"""
import os
import sys

import numpy as np
import torch

torch.set_default_dtype(torch.float64)

SLOPE = 0.01
POS_SCALE, ATTR_SCALE, EYE_POS_SCALE = 4.0, 0.2, 1.0

# Tensors with a gradient (fixed ones - face.lambda, eye.centre - and the
# auto-decoder codes get none from the streams).
GAUSS = ["face.xyz", "face.log_scale", "face.quat", "face.opacity",
         "face.colour", "face.feat", "eye.xyz", "eye.log_scale",
         "eye.opacity", "eye.colour", "eye.feat", "eye.centre_w"]
LIDS = ["face.lid_k"]
MLPS = {"mlp.face_e": 3, "mlp.face_p": 2, "mlp.eye": 3, "mlp.eye_rot0": 2,
        "mlp.eye_rot1": 2}


def trainable_names(cfg):
    names = list(GAUSS) + (LIDS if cfg["n_lid"][0] + cfg["n_lid"][1] else [])
    for m, nl in MLPS.items():
        for l in range(nl):
            names += [f"{m}.l{l}.weight", f"{m}.l{l}.bias"]
    return names


def mlp(x, p, prefix):
    nl = MLPS[prefix]
    for l in range(nl):
        x = x @ p[f"{prefix}.l{l}.weight"].T + p[f"{prefix}.l{l}.bias"]
        if l + 1 < nl:
            x = torch.nn.functional.leaky_relu(x, SLOPE)
    return x


def pe(x):
    parts = [x]
    for k in range(4):
        parts += [torch.sin(2.0 ** k * x), torch.cos(2.0 ** k * x)]
    return torch.cat(parts)


def skew(w):
    z = torch.zeros((), dtype=w.dtype)
    return torch.stack([torch.stack([z, -w[2], w[1]]),
                        torch.stack([w[2], z, -w[0]]),
                        torch.stack([-w[1], w[0], z])])


def rot_x(a):
    c, s = torch.cos(a), torch.sin(a)
    one, z = torch.ones_like(a), torch.zeros_like(a)
    return torch.stack([torch.stack([one, z, z]), torch.stack([z, c, -s]),
                        torch.stack([z, s, c])])


def rot_y(a):
    c, s = torch.cos(a), torch.sin(a)
    one, z = torch.ones_like(a), torch.zeros_like(a)
    return torch.stack([torch.stack([c, z, s]), torch.stack([z, one, z]),
                        torch.stack([-s, z, c])])


def quat_of_rot(r):
    """Unit quaternion (w > 0) of a rotation with positive trace."""
    tr = r[0, 0] + r[1, 1] + r[2, 2]
    assert tr.item() > 0.0, "head rotation beyond 120 degrees"
    w = 0.5 * torch.sqrt(1.0 + tr)
    return torch.stack([w, (r[2, 1] - r[1, 2]) / (4 * w),
                        (r[0, 2] - r[2, 0]) / (4 * w),
                        (r[1, 0] - r[0, 1]) / (4 * w)])


def rot_of_quat(q):
    w, x, y, z = q
    return torch.stack([
        torch.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z),
                     2 * (x * z + w * y)]),
        torch.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z),
                     2 * (y * z - w * x)]),
        torch.stack([2 * (x * z - w * y), 2 * (y * z + w * x),
                     1 - 2 * (x * x + y * y)])])


def quat_mul(a, b):
    """a [4] (x) b [n, 4], Hamilton product, wxyz."""
    aw, av = a[0], a[1:]
    bw, bv = b[:, :1], b[:, 1:]
    w = aw * bw - bv @ av[:, None]
    v = aw * bv + bw * av + torch.cross(av.expand_as(bv), bv, dim=1)
    return torch.cat([w, v], dim=1)


def rvec_of(r):
    """Axis-angle of a rotation (0 < angle < pi), no gradient."""
    r = r.detach()
    ang = torch.acos(((r[0, 0] + r[1, 1] + r[2, 2] - 1) / 2).clamp(-1, 1))
    v = torch.stack([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])
    return v / (2 * torch.sin(ang)) * ang


def face_stream(p, cfg, code, gaze, R):
    n, C = cfg["n_face"], cfg["C"]
    f = p["face.feat"]
    cond = pe(rvec_of(R))
    if not cfg["two_stream"]:
        cond = torch.cat([cond, pe(gaze)])
    oe = mlp(torch.cat([f, code.expand(n, -1)], 1), p, "mlp.face_e")
    op = mlp(torch.cat([f, cond.expand(n, -1)], 1), p, "mlp.face_p")
    lam = p["face.lambda"][:, None]

    def blend(a, b):
        return lam * oe[:, a:b] + (1 - lam) * op[:, a:b]

    x = p["face.xyz"] + POS_SCALE * blend(0, 3)
    feat = p["face.colour"] + oe[:, 3:3 + C] + op[:, 3:3 + C]
    s = p["face.log_scale"] + ATTR_SCALE * blend(3 + C, 6 + C)
    q = p["face.quat"] + ATTR_SCALE * blend(6 + C, 10 + C)
    a = p["face.opacity"] + ATTR_SCALE * blend(10 + C, 11 + C)[:, 0]
    nl0, nl1 = cfg["n_lid"]
    if nl0 + nl1:
        x, q = lids(p, cfg, code, gaze, x, q)
    return x, s, q, a, feat


def lids(p, cfg, code, gaze, x, q):
    """The lid Gaussians turned about their eyeball's centre."""
    nl0, nl1 = cfg["n_lid"]
    nm = cfg["n_face"] - nl0 - nl1
    xs, qs = [x[:nm]], [q[:nm]]
    for e, (b, n) in enumerate(((nm, nl0), (nm + nl0, nl1))):
        ce = p["eye.centre"][e] + p["eye.centre_w"][e] @ code
        knots = p["face.lid_k"][e]
        nv, nu = knots.shape
        for j in range(b, b + n):
            u, v = (float(t) for t in p["face.lid_uv"][j - nm])
            iu = min(max(int(np.floor(u)), 0), nu - 2)
            iv = min(max(int(np.floor(v)), 0), nv - 2)
            fu, fv = u - iu, v - iv
            k = ((1 - fu) * (1 - fv) * knots[iv, iu]
                 + fu * (1 - fv) * knots[iv, iu + 1]
                 + (1 - fu) * fv * knots[iv + 1, iu]
                 + fu * fv * knots[iv + 1, iu + 1])
            a = -k * gaze[0]
            xs.append((ce + rot_x(a) @ (x[j] - ce))[None])
            qx = torch.stack([torch.cos(a / 2), torch.sin(a / 2),
                              torch.zeros_like(a), torch.zeros_like(a)])
            qs.append(quat_mul(qx, q[j:j + 1]))
    return torch.cat(xs), torch.cat(qs)


def eye_stream(p, cfg, code, gaze):
    each, C = cfg["n_eye_each"], cfg["C"]
    pg = pe(gaze)
    rg = rot_y(gaze[1]) @ rot_x(-gaze[0])
    # Sanity of the convention: the rest axis -z goes to the ETH-XGaze gaze
    # vector (-cos p sin y, -sin p, -cos p cos y).
    pi, ya = gaze.detach()
    g = -rg.detach()[:, 2]
    want = torch.stack([-torch.cos(pi) * torch.sin(ya), -torch.sin(pi),
                        -torch.cos(pi) * torch.cos(ya)])
    assert torch.allclose(g, want, atol=1e-12)
    n = 2 * each
    o = mlp(torch.cat([p["eye.feat"], code.expand(n, -1), pg.expand(n, -1)], 1),
            p, "mlp.eye")
    xs = []
    for e in range(2):
        if cfg["eye_rotation"]:
            q = torch.tensor([1.0, 0, 0, 0]) + mlp(pg, p, f"mlp.eye_rot{e}")
            re = rot_of_quat(q / torch.linalg.norm(q)) @ rg
        else:
            re = torch.eye(3)
        ce = p["eye.centre"][e]
        rows = slice(e * each, (e + 1) * each)
        shift = p["eye.centre_w"][e] @ code
        xs.append(ce + shift + (p["eye.xyz"][rows] - ce) @ re.T
                  + EYE_POS_SCALE * o[rows, 0:3])
    x = torch.cat(xs)
    feat = p["eye.colour"] + o[:, 3:3 + C]
    s = (p["eye.log_scale"] + ATTR_SCALE * o[:, 3 + C])[:, None].expand(n, 3)
    a = p["eye.opacity"] + ATTR_SCALE * o[:, 4 + C]
    q = torch.tensor([1.0, 0, 0, 0]).expand(n, 4)
    return x, s, q, a, feat


def run_case(d):
    def load(name):
        return torch.from_numpy(np.load(os.path.join(d, name + ".npy"))
                                .astype(np.float64))

    k = load("config").numpy().astype(int)
    cfg = dict(n_face=k[0], n_eye_each=k[1], F=k[2], D=k[3], C=k[4],
               two_stream=k[5], eye_rotation=k[6], n_lid=(k[7], k[8]))
    names = trainable_names(cfg)
    p = {nm: load("param." + nm).requires_grad_() for nm in names}
    p["face.lambda"] = load("param.face.lambda")
    p["eye.centre"] = load("param.eye.centre")
    if "face.lid_k" in names:
        p["face.lid_uv"] = load("param.face.lid_uv")
    code = load("code").requires_grad_()
    gaze = load("gaze").requires_grad_()
    trans = load("head_t").requires_grad_()
    rot = torch.zeros(3, requires_grad=True)
    R = torch.matrix_exp(skew(rot)) @ load("head_R")

    parts = [face_stream(p, cfg, code, gaze, R)]
    if cfg["two_stream"]:
        parts.append(eye_stream(p, cfg, code, gaze))
    x, s, q, a, feat = (torch.cat(t) for t in zip(*parts))
    mean = x @ R.T + trans
    quat = quat_mul(quat_of_rot(R), q)
    outs = {"mean": mean, "scale": s, "quat": quat, "opac": a, "feat": feat}
    loss = sum((load("v_" + k) * v).sum() for k, v in outs.items())
    inputs = {"code": code, "gaze": gaze, "trans": trans, "rot": rot}
    leaves = [p[nm] for nm in names] + list(inputs.values())
    grads = torch.autograd.grad(loss, leaves, allow_unused=True)

    def save(name, t):
        np.save(os.path.join(d, name + ".npy"),
                t.detach().numpy().astype(np.float32))

    for k, v in outs.items():
        save("out." + k, v)
    for leaf, nm, g in zip(leaves, names + list(inputs), grads):
        save("grad." + nm, torch.zeros_like(leaf) if g is None else g)


def main():
    if len(sys.argv) != 2:
        sys.exit("usage: streams_reference.py DIR")
    cases = sorted(e.path for e in os.scandir(sys.argv[1])
                   if os.path.exists(os.path.join(e.path, "config.npy")))
    if not cases:
        sys.exit(f"no case in {sys.argv[1]} (run test_streams_reference export)")
    for d in cases:
        run_case(d)


if __name__ == "__main__":
    main()
