#!/usr/bin/python3
"""PyTorch reference of the gaze estimator (llm.c style).

Usage: gaze_reference.py OUT_DIR

For each architecture writes OUT_DIR/<arch>.safetensors (an estimator file
with random weights, as the C loader reads it) and adds to
OUT_DIR/reference.safetensors the input image, a random dout, the output
and the gradients of sum(dout * out) for the image and every tensor, all
computed by torch in float64 from the float32 values:
  <arch>.img [3,H,W], <arch>.dout [4], <arch>.out [4], <arch>.dimg [3,H,W],
  <arch>.grad.<tensor name>.
The net (docs/gaze.md): area resize to N x N and of the eye window to
N/2 x 5N/4, minus 0.5, the face and eye branches, fc1 + fc1e, fc2.
"""
import json
import math
import os
import struct
import sys

import numpy as np
import torch
import torch.nn.functional as F

rng = np.random.default_rng(20251122)
WIDTHS = [3, 4, 5, 6]
HIDDEN = 7
N = 32


EYE = (0.1875, 0.8125, 0.28125, 0.53125)  # x0, x1, y0, y1 fractions


def area_matrix(n, m, f0=0.0, f1=1.0):
    """[m, n] weights of the area resize of the window [f0 n, f1 n) of n
    samples to m."""
    M = np.zeros((m, n))
    w = (f1 - f0) * n / m
    for o in range(m):
        a = f0 * n + o * w
        b = a + w
        for i in range(max(math.floor(a), 0), min(math.ceil(b), n)):
            lo, hi = max(i, a), min(i + 1, b)
            if hi > lo:
                M[o, i] = (hi - lo) / (b - a)
    return M


def layers(arch):
    """[(name, kind, in_ch, out_ch)] in file order; kind conv3/conv1/fc."""
    out = []
    if arch == "resnet":
        out += [("stem1", "conv3", 3, WIDTHS[0]), ("stem2", "conv3", WIDTHS[0], WIDTHS[0])]
        for s in range(1, 4):
            out += [(f"s{s}.conv1", "conv3", WIDTHS[s - 1], WIDTHS[s]),
                    (f"s{s}.conv2", "conv3", WIDTHS[s], WIDTHS[s]),
                    (f"s{s}.skip", "conv1", WIDTHS[s - 1], WIDTHS[s])]
    else:
        chans, k = 3, 1
        for s in range(4):
            for _ in range(2 if s < 3 else 1):
                out.append((f"conv{k}", "conv3", chans, WIDTHS[s]))
                chans, k = WIDTHS[s], k + 1
    out += [("eye1", "conv3", 3, WIDTHS[0]), ("eye2", "conv3", WIDTHS[0], WIDTHS[0]),
            ("eye3", "conv3", WIDTHS[0], WIDTHS[1]), ("eye4", "conv3", WIDTHS[1], WIDTHS[2])]
    side = N // 16
    eh, ew = N // 2, 8 * ((5 * N + 16) // 32)
    out += [("fc1", "fc", WIDTHS[3] * side * side, HIDDEN),
            ("fc1e", "fc", WIDTHS[2] * (eh // 8) * (ew // 8), HIDDEN), ("fc2", "fc", HIDDEN, 4)]
    return out


def make_params(arch):
    P = {}
    for name, kind, ic, oc in layers(arch):
        shape = {"conv3": (oc, ic, 3, 3), "conv1": (oc, ic), "fc": (oc, ic)}[kind]
        fan = ic * (9 if kind == "conv3" else 1)
        P[name + ".w"] = (rng.standard_normal(shape) * math.sqrt(2.0 / fan)).astype(np.float32)
        P[name + ".b"] = rng.uniform(-0.1, 0.1, size=(oc,)).astype(np.float32)
    return P


def net(arch, P, img):
    c3 = lambda x, n: F.conv2d(x, P[n + ".w"], P[n + ".b"], padding=1)
    c1 = lambda x, n: F.conv2d(x, P[n + ".w"][:, :, None, None], P[n + ".b"])
    H, W = img.shape[1:]
    Ry = torch.tensor(area_matrix(H, N), dtype=torch.float64)
    Rx = torch.tensor(area_matrix(W, N), dtype=torch.float64)
    x = (torch.einsum("oy,cyx,px->cop", Ry, img, Rx) - 0.5)[None]
    eh, ew = N // 2, 8 * ((5 * N + 16) // 32)
    Ey = torch.tensor(area_matrix(H, eh, EYE[2], EYE[3]), dtype=torch.float64)
    Ex = torch.tensor(area_matrix(W, ew, EYE[0], EYE[1]), dtype=torch.float64)
    e = (torch.einsum("oy,cyx,px->cop", Ey, img, Ex) - 0.5)[None]
    e = F.relu(c3(F.relu(c3(e, "eye1")), "eye2"))
    e = F.avg_pool2d(e, 2)
    e = F.avg_pool2d(F.relu(c3(e, "eye3")), 2)
    e = F.avg_pool2d(F.relu(c3(e, "eye4")), 2)
    if arch == "resnet":
        x = F.relu(c3(F.relu(c3(x, "stem1")), "stem2"))
        for s in range(1, 4):
            x = F.avg_pool2d(x, 2)
            m = c3(F.relu(c3(x, f"s{s}.conv1")), f"s{s}.conv2")
            x = F.relu(m + c1(x, f"s{s}.skip"))
        x = F.avg_pool2d(x, 2)
    else:
        k = 1
        for s in range(4):
            for _ in range(2 if s < 3 else 1):
                x = F.relu(c3(x, f"conv{k}"))
                k += 1
            x = F.avg_pool2d(x, 2)
    x = F.relu(F.linear(x.reshape(1, -1), P["fc1.w"], P["fc1.b"]) +
               F.linear(e.reshape(1, -1), P["fc1e.w"], P["fc1e.b"]))
    return F.linear(x, P["fc2.w"], P["fc2.b"])[0]


def write_safetensors(path, tensors, meta):
    header, off, blobs = {}, 0, []
    for name, arr in tensors.items():
        b = np.ascontiguousarray(arr, dtype="<f4").tobytes()
        header[name] = {"dtype": "F32", "shape": list(arr.shape),
                        "data_offsets": [off, off + len(b)]}
        off += len(b)
        blobs.append(b)
    if meta:
        header["__metadata__"] = meta
    h = json.dumps(header, separators=(",", ":")).encode()
    h += b" " * ((8 - len(h) % 8) % 8)
    with open(path, "wb") as f:
        f.write(struct.pack("<Q", len(h)) + h + b"".join(blobs))


def main():
    out_dir = sys.argv[1]
    os.makedirs(out_dir, exist_ok=True)
    ref = {}
    for arch, (H, W) in (("resnet", (40, 52)), ("vgg", (64, 48))):
        P = make_params(arch)
        meta = {"format": "gazesplat-gaze-estimator", "format_version": "1", "arch": arch,
                "input_size": str(N), "widths": ",".join(map(str, WIDTHS)),
                "hidden": str(HIDDEN)}
        write_safetensors(f"{out_dir}/{arch}.safetensors", P, meta)
        img = rng.uniform(0, 1, size=(3, H, W)).astype(np.float32)
        dout = rng.uniform(-1, 1, size=(4,)).astype(np.float32)
        T = {k: torch.tensor(v, dtype=torch.float64, requires_grad=True) for k, v in P.items()}
        x = torch.tensor(img, dtype=torch.float64, requires_grad=True)
        out = net(arch, T, x)
        out.backward(torch.tensor(dout, dtype=torch.float64))
        ref[f"{arch}.img"] = img
        ref[f"{arch}.dout"] = dout
        ref[f"{arch}.out"] = out.detach().numpy()
        ref[f"{arch}.dimg"] = x.grad.numpy()
        for k, v in T.items():
            ref[f"{arch}.grad.{k}"] = v.grad.numpy()
    write_safetensors(f"{out_dir}/reference.safetensors", ref, None)


main()
