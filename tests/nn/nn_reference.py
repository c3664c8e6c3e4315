#!/usr/bin/python3
"""Writes the PyTorch reference for the gs_nn kernels (llm.c style).

Usage: nn_reference.py OUT_FILE

Inputs are drawn from a seeded generator and rounded to float32 (so both
sides see the same numbers); forward and backward then run in torch in
float64, with dout a random tensor of the output's shape (the gradient of
the random linear functional sum(dout * out)). Adam runs in float32, as
torch.optim.Adam does for float32 parameters.

File format, little-endian:
  8 bytes  magic "GSNNREF\\0"
  u32      version (1)
  u32      tensor count
  per tensor: u32 name length, name bytes (no NUL), u32 ndim (1..8),
              u32 dims[ndim], float32 data[prod(dims)]
Names are "<case>.<tensor>"; gradients are "<case>.d<input>".
"""
import struct
import sys

import numpy as np
import torch
import torch.nn.functional as F

MAGIC = b"GSNNREF\0"
VERSION = 1

rng = np.random.default_rng(20250611)
tensors = []


def put(name, arr):
    arr = np.array(arr, dtype=np.float32, copy=True)  # never a view of a live tensor
    if arr.ndim == 0:
        arr = arr.reshape(1)
    tensors.append((name, arr))


def uniform(shape, lo=-1.0, hi=1.0):
    return rng.uniform(lo, hi, size=shape).astype(np.float32)


def case(name, inputs, fn, scalars=None):
    """Runs fn(**inputs) forward and backward in float64 and stores inputs,
    out, dout and the gradient of every input."""
    leaves = {k: torch.tensor(v, dtype=torch.float64, requires_grad=True)
              for k, v in inputs.items()}
    out = fn(**leaves)
    dout = uniform(tuple(out.shape)) if out.dim() else uniform((1,), 0.5, 2.0)
    out.backward(torch.tensor(dout, dtype=torch.float64).reshape(out.shape))
    for k, v in inputs.items():
        put(f"{name}.{k}", v)
        put(f"{name}.d{k}", leaves[k].grad.numpy())
    put(f"{name}.out", out.detach().numpy())
    put(f"{name}.dout", dout)
    for k, v in (scalars or {}).items():
        put(f"{name}.{k}", np.array([v]))


def gauss_window():
    k = torch.arange(11, dtype=torch.float64) - 5
    g = torch.exp(-(k * k) / (2 * 1.5 ** 2))
    return g / g.sum()


def ssim_loss(x, y, pad):
    """1 - mean SSIM, 11x11 Gaussian sigma 1.5, C1 = 0.01^2, C2 = 0.03^2;
    pad 0 = valid windows, 5 = zero padding."""
    C = x.shape[0]
    g = gauss_window()
    w = (g[:, None] * g[None, :]).expand(C, 1, 11, 11)

    def filt(t):
        return F.conv2d(t[None], w, padding=pad, groups=C)[0]

    mx, my = filt(x), filt(y)
    sxx = filt(x * x) - mx * mx
    syy = filt(y * y) - my * my
    sxy = filt(x * y) - mx * my
    c1, c2 = 0.01 ** 2, 0.03 ** 2
    s = ((2 * mx * my + c1) * (2 * sxy + c2)) / \
        ((mx * mx + my * my + c1) * (sxx + syy + c2))
    return 1 - s.mean()


def blur(x):
    C = x.shape[0]
    k = torch.tensor([1.0, 2.0, 1.0], dtype=torch.float64)
    k = (k[:, None] * k[None, :]) / 16
    xp = F.pad(x[None], (1, 1, 1, 1), mode="reflect")
    return F.conv2d(xp, k.expand(C, 1, 3, 3), groups=C)[0]


def attention(x, code, wk, bk, wv, bv, temp):
    """The unfolded GazeGaussian attention over x [C, H*W]."""
    k = wk @ x + bk[:, None]
    att = torch.softmax((code @ k) / temp, dim=0)
    v = wv @ x + bv[:, None]
    return x + (v @ att)[:, None]


def signed(shape, lo, hi):
    """Magnitudes in [lo, hi) with random signs (away from kinks at 0)."""
    return uniform(shape, lo, hi) * rng.choice([-1.0, 1.0], size=shape).astype(np.float32)


def kernels():
    case("linear", {"in": uniform((5, 7)), "w": uniform((6, 7)), "b": uniform(6)},
         lambda **t: F.linear(t["in"], t["w"], t["b"]))
    case("conv1x1", {"in": uniform((5, 4 * 5)), "w": uniform((6, 5)), "b": uniform(6)},
         lambda **t: F.conv2d(t["in"].reshape(1, 5, 4, 5), t["w"][:, :, None, None],
                              t["b"])[0].reshape(6, 20))
    case("conv3x3", {"in": uniform((3, 6, 7)), "w": uniform((4, 3, 3, 3)), "b": uniform(4)},
         lambda **t: F.conv2d(t["in"][None], t["w"], t["b"], padding=1)[0])
    case("relu", {"in": signed(40, 0.01, 3.0)}, lambda **t: torch.relu(t["in"]))
    case("leaky_relu", {"in": signed(40, 0.01, 3.0)},
         lambda **t: F.leaky_relu(t["in"], 0.2), {"slope": 0.2})
    extreme = np.array([-100, -88, -40, -20, 20, 40, 88, 100], dtype=np.float32)
    case("tanh", {"in": np.concatenate([uniform(32, -6, 6), extreme])},
         lambda **t: torch.tanh(t["in"]))
    case("sigmoid", {"in": np.concatenate([uniform(32, -6, 6), extreme])},
         lambda **t: torch.sigmoid(t["in"]))
    case("softmax", {"in": uniform(37, -10, 10)}, lambda **t: torch.softmax(t["in"], 0))
    case("pixel_shuffle", {"in": uniform((12, 3, 4))},
         lambda **t: F.pixel_shuffle(t["in"][None], 2)[0])
    for nm, shape in (("upsample2x", (2, 4, 5)), ("upsample2x_1x3", (1, 1, 3))):
        case(nm, {"in": uniform(shape)},
             lambda **t: F.interpolate(t["in"][None], scale_factor=2, mode="bilinear",
                                       align_corners=False)[0])
    case("blur", {"in": uniform((2, 5, 6))}, lambda **t: blur(t["in"]))
    case("blur_2x2", {"in": uniform((1, 2, 2))}, lambda **t: blur(t["in"]))
    for nm, shape in (("avgpool2x", (3, 4, 6)), ("avgpool2x_2x2", (1, 2, 2))):
        case(nm, {"in": uniform(shape)}, lambda **t: F.avg_pool2d(t["in"][None], 2)[0])
    C, D, HW, temp = 8, 12, 30, 3.0
    case("attention",
         {"x": uniform((C, HW)), "code": uniform(D), "wk": uniform((D, C)),
          "bk": uniform(D), "wv": uniform((C, C)), "bv": uniform(C)},
         lambda **t: attention(temp=temp, **t), {"temp": temp})
    a, b, m = uniform((3, 24), 0, 1), uniform((3, 24), 0, 1), uniform(24, 0, 1)
    case("l1", {"a": a, "b": b}, lambda **t: (t["a"] - t["b"]).abs().sum() / a.size)
    case("l1_mask", {"a": a, "b": b, "mask": m},
         lambda **t: (t["mask"][None] * (t["a"] - t["b"]).abs()).sum() / a.size)
    y = uniform((3, 16, 18), 0, 1)
    x = (0.7 * y + uniform(y.shape, 0, 0.3)).astype(np.float32)
    case("ssim_valid", {"x": x, "y": y}, lambda **t: ssim_loss(t["x"], t["y"], 0))
    case("ssim_zero", {"x": x, "y": y}, lambda **t: ssim_loss(t["x"], t["y"], 5))


def adam():
    """Six steps of torch.optim.Adam (float32) over two groups with lr
    multipliers, with clip_grad_norm_ at 0.5 (the first step clips)."""
    lr, mults, max_norm, steps = 0.01, (1.0, 0.3), 0.5, 6
    p0, p1 = uniform(5), uniform(3)
    put("adam.lr", np.array([lr]))
    put("adam.lr_mult", np.array(mults))
    put("adam.max_norm", np.array([max_norm]))
    put("adam.steps", np.array([steps]))
    put("adam.p0", p0)
    put("adam.p1", p1)
    t0 = torch.tensor(p0, requires_grad=True)
    t1 = torch.tensor(p1, requires_grad=True)
    opt = torch.optim.Adam([{"params": [t0], "lr": lr * mults[0]},
                            {"params": [t1], "lr": lr * mults[1]}],
                           lr=lr, betas=(0.9, 0.999), eps=1e-8)
    for step in range(steps):
        scale = 1.0 if step == 0 else 0.05
        g0, g1 = uniform(5, -scale, scale), uniform(3, -scale, scale)
        t0.grad = torch.tensor(g0)
        t1.grad = torch.tensor(g1)
        norm = torch.nn.utils.clip_grad_norm_([t0, t1], max_norm)
        opt.step()
        put(f"adam.step{step}.g0", g0)
        put(f"adam.step{step}.g1", g1)
        put(f"adam.step{step}.norm", np.array([norm.item()]))
        put(f"adam.step{step}.p0", t0.detach().numpy())
        put(f"adam.step{step}.p1", t1.detach().numpy())


def write(path):
    with open(path, "wb") as f:
        f.write(MAGIC + struct.pack("<II", VERSION, len(tensors)))
        for name, arr in tensors:
            nb = name.encode()
            f.write(struct.pack("<I", len(nb)) + nb)
            f.write(struct.pack("<I", arr.ndim) + struct.pack(f"<{arr.ndim}I", *arr.shape))
            f.write(arr.astype("<f4").tobytes())


def main():
    if len(sys.argv) != 2:
        sys.exit("usage: nn_reference.py OUT_FILE")
    torch.set_num_threads(1)
    kernels()
    adam()
    write(sys.argv[1])
    print(f"wrote {len(tensors)} tensors to {sys.argv[1]} (torch {torch.__version__})")


if __name__ == "__main__":
    main()
