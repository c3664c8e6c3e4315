#!/usr/bin/python3
"""Writes the PyTorch reference for the neural renderer (lib/model/renderer.c).

Usage: renderer_reference.py OUT_DIR

For each guidance mode (none, additive, multiplicative) the network is built
in torch from its definition (not from the C code): the guidance in its
UNFOLDED form, with a key k_p = Wk x_p + bk and a value v_p = Wv x_p + bv
per pixel and a random key bias bk, which the C code drops because it
cancels in the softmax. Weights, x, tau and the upstream gradient dout are
drawn from a seeded generator and rounded to float32 (both sides see the
same numbers); forward and backward run in float64.

Files, all float32 .npy, in OUT_DIR/<mode>/:
  param.<tensor name>.npy   every tensor of the C layout, e.g.
                            param.renderer.block0.conv_a.weight.npy [out, in]
  grad.<tensor name>.npy    d(sum(dout * out)) / d(tensor)
  x.npy [C,H,W], tau.npy [D], dout.npy [3,4H,4W], out.npy [3,4H,4W],
  dx.npy, dtau.npy, unused.key_bias.npy [D]
  and for the source modes src.npy [C,H,W] and dsrc.npy.

The source modes (GS_GUIDE_SRC_SOURCE): ONE guidance vector, the attention
of tau over the pixels of a separate map src, added (or multiplied in) after
both blocks.
"""
import math
import os
import sys

import numpy as np
import torch
import torch.nn.functional as F

C, D, H, W = 32, 144, 8, 12
MODES = ("none", "additive", "multiplicative", "source_additive",
         "source_multiplicative")
SLOPE = 0.2

rng = np.random.default_rng(20250612)


def uniform(shape, bound):
    return rng.uniform(-bound, bound, size=shape).astype(np.float32)


def layout(guided):
    """(name, shape) of every parameter tensor, in the C layout's order."""
    t = []

    def conv(prefix, out, inp):
        t.append((prefix + ".weight", (out, inp)))
        t.append((prefix + ".bias", (out,)))

    conv("renderer.conv_rgb", 3, C)
    for b in range(2):
        conv(f"renderer.block{b}.conv_a", 2 * C, C)
        conv(f"renderer.block{b}.conv_b", 4 * C, 2 * C)
        conv(f"renderer.block{b}.conv_c", C, C)
        conv(f"renderer.block{b}.conv_rgb", 3, C)
    if guided:
        t.append(("renderer.guide.key.weight", (D, C)))
        t.append(("renderer.guide.value.weight", (C, C)))
        t.append(("renderer.guide.value.bias", (C,)))
    return t


def blur(t):
    """[1,2,1] x [1,2,1] / 16 per channel, reflect border; t [1,C,H,W]."""
    k = torch.tensor([1.0, 2.0, 1.0], dtype=torch.float64)
    k2 = (k[:, None] * k[None, :]) / 16.0
    n = t.shape[1]
    return F.conv2d(F.pad(t, (1, 1, 1, 1), mode="reflect"),
                    k2.expand(n, 1, 3, 3), groups=n)


def up2x(t):
    return F.interpolate(t, scale_factor=2, mode="bilinear", align_corners=False)


def conv(t, p, prefix):
    return F.conv2d(t, p[prefix + ".weight"][:, :, None, None], p[prefix + ".bias"])


def attend(z, tau, p, bk):
    """Cross-attention of tau over the pixels of z [C,HW], unfolded: [C]."""
    k = p["renderer.guide.key.weight"] @ z + bk[:, None]            # [D, HW]
    att = torch.softmax((tau @ k) / math.sqrt(D), dim=0)            # [HW]
    v = p["renderer.guide.value.weight"] @ z + p["renderer.guide.value.bias"][:, None]
    return v @ att


def guide(u, tau, p, bk, mode, avec):
    """The guidance after a block: over u itself, or with the source's avec."""
    if mode == "none":
        return u
    n, c, h, w = u.shape
    a = avec if avec is not None else attend(u.reshape(c, h * w), tau, p, bk)
    a = a.reshape(1, c, 1, 1)
    return u + a if mode.endswith("additive") else u + u * a


def renderer(x, tau, p, bk, mode, src):
    avec = None
    if mode.startswith("source"):
        avec = attend(src.reshape(C, H * W), tau, p, bk)
    x = x[None]
    rgb = blur(up2x(conv(x, p, "renderer.conv_rgb")))
    for b in range(2):
        pre = f"renderer.block{b}"
        y = F.leaky_relu(conv(x, p, pre + ".conv_a"), SLOPE)
        y = F.leaky_relu(conv(y, p, pre + ".conv_b"), SLOPE)
        x = blur(F.pixel_shuffle(y + x.repeat(1, 4, 1, 1), 2))
        x = F.leaky_relu(conv(x, p, pre + ".conv_c"), SLOPE)
        x = guide(x, tau, p, bk, mode, avec)
        rgb = rgb + conv(x, p, pre + ".conv_rgb")
        if b == 0:
            rgb = blur(up2x(rgb))
    return torch.sigmoid(rgb)[0]


def leaf(a):
    return torch.tensor(a, dtype=torch.float64, requires_grad=True)


def save(path, a):
    np.save(path, np.asarray(a, dtype=np.float32))


def one_mode(out_dir, mode):
    d = os.path.join(out_dir, mode)
    os.makedirs(d, exist_ok=True)
    params, fan_in = {}, 1
    for name, shape in layout(mode != "none"):
        if len(shape) == 2:
            fan_in = shape[1]  # the bias that follows shares it
        # the value projection at the default bound too (not zero, as the
        # C init makes it), so that every path carries a gradient
        params[name] = uniform(shape, 1.0 / math.sqrt(fan_in))
    bk = uniform(D, 1.0)
    x = uniform((C, H, W), 1.0)
    tau = uniform(D, 8.0)  # logits spread over about +-1: a peaked attention
    dout = uniform((3, 4 * H, 4 * W), 1.0)

    src = uniform((C, H, W), 1.0)
    p = {k: leaf(v) for k, v in params.items()}
    tx, ttau, tbk, tsrc = leaf(x), leaf(tau), leaf(bk), leaf(src)
    out = renderer(tx, ttau, p, tbk, mode, tsrc)
    out.backward(torch.tensor(dout, dtype=torch.float64))
    if mode != "none":
        assert float(tbk.grad.abs().max()) < 1e-9, "the key bias must cancel"

    for k, v in params.items():
        save(os.path.join(d, f"param.{k}.npy"), v)
        save(os.path.join(d, f"grad.{k}.npy"), p[k].grad.numpy())
    save(os.path.join(d, "unused.key_bias.npy"), bk)
    save(os.path.join(d, "x.npy"), x)
    save(os.path.join(d, "tau.npy"), tau)
    save(os.path.join(d, "dout.npy"), dout)
    save(os.path.join(d, "out.npy"), out.detach().numpy())
    save(os.path.join(d, "dx.npy"), tx.grad.numpy())
    dtau = ttau.grad.numpy() if ttau.grad is not None else np.zeros(D)
    save(os.path.join(d, "dtau.npy"), dtau)
    if mode.startswith("source"):
        save(os.path.join(d, "src.npy"), src)
        save(os.path.join(d, "dsrc.npy"), tsrc.grad.numpy())


def main():
    if len(sys.argv) != 2:
        sys.exit("usage: renderer_reference.py OUT_DIR")
    torch.set_num_threads(1)
    for mode in MODES:
        one_mode(sys.argv[1], mode)


if __name__ == "__main__":
    main()
