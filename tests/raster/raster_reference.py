#!/usr/bin/env python3
"""Dense float64 PyTorch reference for gs_raster (llm.c style).

Implements the projection and compositing documented in
lib/include/gazesplat/raster.h densely in torch, differentiates it with
autograd in float64, and writes seeded scenes with their inputs, upstream
gradients, outputs and parameter gradients to a versioned binary file that
tests/raster/test_raster_reference.c reads.

Usage:
  raster_reference.py OUT.bin      write the reference scenes
  raster_reference.py --selfcheck  check this reference against a naive
                                   sequential compositor and against
                                   float64 finite differences

File format (little endian):
  8 bytes  magic "GSRASTRF"
  u32      version (1)
  u32      number of scenes
  u32      number of tensors
  tensors: u32 name length, name (ASCII, no NUL), u32 ndim, u32 dims[ndim],
           float32 data (row-major).
Scene k's tensors are named "s<k>.<field>"; see SceneWriter.scene().
"""
import math
import struct
import sys

import torch

MAGIC = b"GSRASTRF"
VERSION = 1


def f32(x):
    """The float32 value of a C constant written as a float literal."""
    return struct.unpack("<f", struct.pack("<f", x))[0]


# Frozen constants of raster.h, as the float32 values the C code uses.
TILE = 16
NEAR = f32(0.01)
FAR = f32(1e10)
EPS2D = f32(0.3)
MARGIN = f32(0.15)
MAX_ALPHA = f32(0.99)
MIN_ALPHA = f32(1.0 / 255.0)
T_EPS = f32(1e-4)

DT = torch.float64


# ---------------------------------------------------------------- projection

def quat_to_rot(q):
    """q: N x 4 wxyz, any norm; zero = identity. Returns N x 3 x 3."""
    n = q.norm(dim=1, keepdim=True)
    zero = n == 0
    ident = torch.tensor([1.0, 0.0, 0.0, 0.0], dtype=q.dtype).expand_as(q)
    qn = torch.where(zero, ident, q / torch.where(zero, torch.ones_like(n), n))
    w, x, y, z = qn.unbind(1)
    rows = [
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ]
    return torch.stack(rows, dim=1).reshape(-1, 3, 3)


def project(cam, g, antialiased):
    """Per-Gaussian screen quantities, differentiable w.r.t. g's tensors.

    cam: dict fx fy cx cy width height viewmat (3x4 tensor).
    g: dict means N3, log_scales N3, quats N4, opacity_logits N.
    Returns dict mean2d N2, conic N3 (a, b, c), opacity N, depth N,
    and detached radius N, valid N (bool), plus diagnostics."""
    fx, fy, cx, cy = cam["fx"], cam["fy"], cam["cx"], cam["cy"]
    W, H = cam["width"], cam["height"]
    V = cam["viewmat"][:, :3]
    t = cam["viewmat"][:, 3]

    R = quat_to_rot(g["quats"])
    M = R * torch.exp(g["log_scales"])[:, None, :]      # R S: scale columns
    sigma = M @ M.transpose(1, 2)                        # N x 3 x 3
    mean_c = g["means"] @ V.T + t                        # N x 3
    sigma_c = V @ sigma @ V.T
    x, y, z = mean_c.unbind(1)

    lim_xp = (W - cx) / fx + MARGIN * W / fx
    lim_xn = cx / fx + MARGIN * W / fx
    lim_yp = (H - cy) / fy + MARGIN * H / fy
    lim_yn = cy / fy + MARGIN * H / fy
    tx = z * torch.clamp(x / z, -lim_xn, lim_xp)
    ty = z * torch.clamp(y / z, -lim_yn, lim_yp)
    zero = torch.zeros_like(z)
    J = torch.stack([fx / z, zero, -fx * tx / (z * z),
                     zero, fy / z, -fy * ty / (z * z)], dim=1).reshape(-1, 2, 3)
    cov2 = J @ sigma_c @ J.transpose(1, 2)              # N x 2 x 2
    det_orig = cov2[:, 0, 0] * cov2[:, 1, 1] - cov2[:, 0, 1] * cov2[:, 1, 0]
    s00 = cov2[:, 0, 0] + EPS2D
    s11 = cov2[:, 1, 1] + EPS2D
    s01 = cov2[:, 0, 1]
    det = s00 * s11 - s01 * s01

    valid = (z >= NEAR) & (z <= FAR) & (det > 0)
    safe_det = torch.where(valid, det, torch.ones_like(det))
    conic = torch.stack([s11 / safe_det, -s01 / safe_det, s00 / safe_det], 1)
    opacity = torch.sigmoid(g["opacity_logits"])
    comp = torch.sqrt(torch.clamp(det_orig / safe_det, min=0.0))
    if antialiased:
        opacity = opacity * comp

    with torch.no_grad():
        b = 0.5 * (s00 + s11)
        v1 = b + torch.sqrt(torch.clamp(b * b - det, min=0.01))
        r3 = 3.0 * torch.sqrt(v1)
        radius = torch.ceil(r3)

    mean2d = torch.stack([fx * x / z + cx, fy * y / z + cy], 1)
    with torch.no_grad():
        m = mean2d
        off = ((m[:, 0] + radius <= 0) | (m[:, 0] - radius >= W) |
               (m[:, 1] + radius <= 0) | (m[:, 1] - radius >= H))
        valid = valid & ~off
    return dict(mean2d=mean2d, conic=conic, opacity=opacity, depth=z,
                radius=radius, r3=r3, valid=valid, comp=comp,
                xz=(x / z).detach(), yz=(y / z).detach(),
                lims=(lim_xn, lim_xp, lim_yn, lim_yp))


def tile_ranges(mean2d, radius, W, H):
    """[tmin, tmax) tile ranges per Gaussian, gsplat's rule. N x 2 each."""
    tw, th = -(-W // TILE), -(-H // TILE)
    lo = torch.floor((mean2d.detach() - radius[:, None]) / TILE)
    hi = torch.ceil((mean2d.detach() + radius[:, None]) / TILE)
    lim = torch.tensor([tw, th], dtype=DT)
    lo = torch.minimum(torch.clamp(lo, min=0), lim)
    hi = torch.minimum(torch.clamp(hi, min=0), lim)
    return lo.long(), hi.long()


# ---------------------------------------------------------------- compositing

def composite_tile(p, idx, px, py):
    """Dense compositing of one tile.

    idx: K Gaussian indices sorted by (depth, index); px, py: the P pixel
    centres. Returns a dict of P x K tensors: w, the compositing weights
    (differentiable), and detached masks and values for diagnostics."""
    m = p["mean2d"][idx]
    cn = p["conic"][idx]
    dx = m[None, :, 0] - px[:, None]                     # P x K
    dy = m[None, :, 1] - py[:, None]
    sig = 0.5 * (cn[None, :, 0] * dx * dx + cn[None, :, 2] * dy * dy) \
        + cn[None, :, 1] * dx * dy
    raw = p["opacity"][idx][None, :] * torch.exp(-sig)
    clamped = raw.detach() > MAX_ALPHA
    alpha = torch.where(clamped, torch.full_like(raw, MAX_ALPHA), raw)
    use = (sig.detach() >= 0) & (alpha.detach() >= MIN_ALPHA)
    a = torch.where(use, alpha, torch.zeros_like(alpha))
    one_m = 1 - a
    tin = torch.cat([torch.ones_like(a[:, :1]),
                     torch.cumprod(one_m, dim=1)[:, :-1]], dim=1)
    stop = (a.detach() > 0) & (tin.detach() * one_m.detach() <= T_EPS)
    nstop = torch.cumsum(stop.long(), dim=1)
    keep = nstop == 0
    w = a * tin * keep
    reached = (nstop - stop.long()) == 0     # up to and including the stop
    return dict(w=w, raw=raw.detach(), use=use & keep, stop=stop & reached,
                reached=reached, clamped=clamped & use & keep,
                tin=tin.detach(), one_m=one_m.detach())


def sort_order(depth):
    """Indices sorted by (depth, index)."""
    return torch.sort(depth.detach(), stable=True).indices


def render(cam, g, bg, antialiased, diag=None):
    """Returns features C x H x W, alpha H x W, depth H x W, and the
    projection and tile ranges. diag, a list, receives each tile's
    compositing state."""
    W, H = cam["width"], cam["height"]
    C = g["features"].shape[1]
    p = project(cam, g, antialiased)
    lo, hi = tile_ranges(p["mean2d"], p["radius"], W, H)
    order = sort_order(p["depth"])
    order = order[p["valid"][order]]
    tiles_out = []
    for ty in range(-(-H // TILE)):
        for tx in range(-(-W // TILE)):
            x0, y0 = tx * TILE, ty * TILE
            x1, y1 = min(x0 + TILE, W), min(y0 + TILE, H)
            ys, xs = torch.meshgrid(torch.arange(y0, y1, dtype=DT),
                                    torch.arange(x0, x1, dtype=DT),
                                    indexing="ij")
            px, py = xs.reshape(-1) + 0.5, ys.reshape(-1) + 0.5
            inside = ((lo[order, 0] <= tx) & (tx < hi[order, 0]) &
                      (lo[order, 1] <= ty) & (ty < hi[order, 1]))
            idx = order[inside]
            P = px.shape[0]
            if idx.numel() == 0:
                f = torch.zeros(P, C, dtype=DT)
                a_sum = torch.zeros(P, dtype=DT)
                d = torch.zeros(P, dtype=DT)
            else:
                t = composite_tile(p, idx, px, py)
                w = t["w"]
                f = w @ g["features"][idx]
                a_sum = w.sum(1)
                d = w @ p["depth"][idx]
                if diag is not None:
                    diag.append(dict(tile=(tx, ty), idx=idx, px=px, py=py, **t))
            if bg is not None:
                f = f + (1 - a_sum)[:, None] * \
                    bg[:, y0:y1, x0:x1].reshape(C, -1).T
            h, w_ = y1 - y0, x1 - x0
            tiles_out.append((f.T.reshape(C, h, w_), a_sum.reshape(h, w_),
                              d.reshape(h, w_)))
    # Assemble with cat so autograd sees one graph.
    rows_f, rows_a, rows_d = [], [], []
    ntx = -(-W // TILE)
    for r in range(0, len(tiles_out), ntx):
        row = tiles_out[r:r + ntx]
        rows_f.append(torch.cat([t[0] for t in row], dim=2))
        rows_a.append(torch.cat([t[1] for t in row], dim=1))
        rows_d.append(torch.cat([t[2] for t in row], dim=1))
    return (torch.cat(rows_f, dim=1), torch.cat(rows_a, dim=0),
            torch.cat(rows_d, dim=0), p, lo, hi)


# ---------------------------------------------------------------- scenes

def look_at_viewmat(yaw, pitch, dist):
    """A world-to-camera [R | t] looking at the origin from distance dist."""
    cyw, syw = math.cos(yaw), math.sin(yaw)
    cp, sp = math.cos(pitch), math.sin(pitch)
    Ry = torch.tensor([[cyw, 0, syw], [0, 1, 0], [-syw, 0, cyw]], dtype=DT)
    Rx = torch.tensor([[1, 0, 0], [0, cp, -sp], [0, sp, cp]], dtype=DT)
    R = Rx @ Ry
    t = torch.tensor([0.0, 0.0, dist], dtype=DT)
    return torch.cat([R, t[:, None]], dim=1)


def as_f32(t):
    """Rounds to float32 values (the C side sees exactly these)."""
    return t.to(torch.float32).to(DT)


def make_scene(spec):
    gen = torch.Generator().manual_seed(spec["seed"])
    N, C, W, H = spec["n"], spec["channels"], spec["width"], spec["height"]

    def u(*shape, lo=0.0, hi=1.0):
        return lo + (hi - lo) * torch.rand(*shape, generator=gen, dtype=DT)

    def nrm(*shape):
        return torch.randn(*shape, generator=gen, dtype=DT)

    fx = spec.get("fx", 70.0)
    fy = spec.get("fy", fx * 1.05)
    cam = dict(fx=f32(fx), fy=f32(fy), cx=f32(W * 0.47), cy=f32(H * 0.53),
               width=W, height=H,
               viewmat=as_f32(look_at_viewmat(0.3, -0.2, 4.0)))
    # Camera-space points: 60% spread past the image edges (some straddle borders, some are
    # off-screen), 40% in a dense, opaque central cluster so that pixels
    # there stop early and alphas clamp.
    ns = int(N * 0.6)
    nb = N - ns
    sx = 4.0 * (W / 2) / cam["fx"]
    sy = 4.0 * (H / 2) / cam["fy"]
    spread = torch.stack([u(ns, lo=-1.2, hi=1.2) * sx,
                          u(ns, lo=-1.2, hi=1.2) * sy,
                          u(ns, lo=-1.2, hi=1.2)], 1)
    blob = torch.stack([nrm(nb) * 0.25 * sx, nrm(nb) * 0.25 * sy,
                        u(nb, lo=-1.0, hi=1.0)], 1)
    cam_pts = torch.cat([spread, blob], 0)
    cam_pts[:, 2] += 4.0
    logits = torch.cat([u(ns, lo=-1.5, hi=6.0), u(nb, lo=2.0, hi=12.0)])
    log_scales = u(N, 3, lo=math.log(0.04), hi=math.log(0.25))
    # The last few are large, opaque and in front: their centres clamp alpha.
    nf = min(8, N // 10)
    front = slice(N - nf, N)
    cam_pts[front, 2] = u(nf, lo=2.6, hi=3.2)
    log_scales[front] = u(nf, 3, lo=math.log(0.3), hi=math.log(0.5))
    logits[front] = u(nf, lo=9.0, hi=12.0)
    Vt = cam["viewmat"]
    means = (cam_pts - Vt[:, 3]) @ Vt[:, :3]     # world = R^T (c - t)
    g = dict(
        means=as_f32(means),
        log_scales=as_f32(log_scales),
        quats=as_f32(nrm(N, 4) * u(N, 1, lo=0.5, hi=2.0)),
        opacity_logits=as_f32(logits),
        features=as_f32(u(N, C, lo=-0.5, hi=1.5)),
    )
    bg = None
    if spec["background"] == "constant":
        bg = as_f32(u(C, 1, 1).expand(C, H, W).clone())
    elif spec["background"] == "pixel":
        bg = as_f32(u(C, H, W))
    ups = dict(v_features=as_f32(nrm(C, H, W)), v_alpha=as_f32(nrm(H, W)),
               v_depth=as_f32(nrm(H, W) * 0.1))
    return cam, g, bg, ups


def margins(cam, g, bg, aa):
    """Gaussians whose discrete decisions (radius rounding, tile and cull
    box edges, the 1/255 skip, the 0.99 clamp, the early stop, depth order,
    the Jacobian clamp) sit so close to a threshold that float32 rounding
    could flip them. Returns the set of their indices and diagnostics."""
    diag = []
    with torch.no_grad():
        _, _, _, p, lo, hi = render(cam, g, bg, aa, diag)
    W, H = cam["width"], cam["height"]
    bad = set()
    vis = p["valid"]
    r3 = p["r3"]
    near_int = (r3 - torch.round(r3)).abs() < 2e-3
    bad |= set(torch.nonzero(near_int & vis).flatten().tolist())
    for axis, size in ((0, W), (1, H)):
        for e in (p["mean2d"][:, axis] - p["radius"],
                  p["mean2d"][:, axis] + p["radius"]):
            dist = (e - TILE * torch.round(e / TILE)).abs()
            dist = torch.minimum(dist, (e - size).abs())
            bad |= set(torch.nonzero(dist < 2e-3).flatten().tolist())
    lims = p["lims"]
    for v, ln, lp in ((p["xz"], lims[0], lims[1]), (p["yz"], lims[2], lims[3])):
        close = ((v + ln).abs() < 1e-4) | ((v - lp).abs() < 1e-4)
        bad |= set(torch.nonzero(close).flatten().tolist())
    stats = dict(pairs=0, clamped=0, stopped_pixels=0, contrib=[],
                 binned_out=0)
    for t in diag:
        idx, raw, tin, one_m = t["idx"], t["raw"], t["tin"], t["one_m"]
        reached = t["reached"]
        near_skip = reached & ((raw.log() - math.log(MIN_ALPHA)).abs() < 1e-4)
        near_clamp = reached & ((raw / MAX_ALPHA - 1).abs() < 1e-4)
        live = t["use"] | t["stop"]
        tv = tin * one_m
        near_stop = live & ((tv.log() - math.log(T_EPS)).abs() < 5e-4)
        worry = near_skip | near_clamp | near_stop
        for k in torch.nonzero(worry.any(0)).flatten().tolist():
            bad.add(int(idx[k]))
        # A clamped stopping alpha cannot move: nudge the last unclamped
        # contributor, which sets T, as well.
        movable = t["use"] & ~t["clamped"]
        for px in torch.nonzero(near_stop.any(1)).flatten().tolist():
            ks = torch.nonzero(movable[px]).flatten()
            if ks.numel():
                bad.add(int(idx[ks[-1]]))
        # Depth order within the tile must not hinge on float32 rounding.
        d = p["depth"][idx]
        if d.numel() > 1:
            gap = (d[1:] - d[:-1]) / d[1:]
            for k in torch.nonzero(gap < 1e-5).flatten().tolist():
                bad.add(int(idx[k]))
                bad.add(int(idx[k + 1]))
        stats["pairs"] += int(t["use"].sum())
        stats["clamped"] += int(t["clamped"].sum())
        stats["stopped_pixels"] += int(t["stop"].any(1).sum())
        stats["contrib"].append(t["use"].sum(1))
    stats["visible"] = int(vis.sum())
    stats["intersections"] = int(((hi - lo).prod(1) * vis).sum())
    m = p["mean2d"]
    stats["straddling"] = int((vis & ((m[:, 0] < 0) | (m[:, 0] >= W) |
                                      (m[:, 1] < 0) | (m[:, 1] >= H))).sum())
    stats["offscreen_culled"] = int((~vis).sum())
    outside = ((p["xz"] < -lims[0]) | (p["xz"] > lims[1]) |
               (p["yz"] < -lims[2]) | (p["yz"] > lims[3]))
    stats["jacobian_clamped"] = int((vis & outside).sum())
    stats["min_comp"] = float(p["comp"][vis].min()) if vis.any() else 0.0
    contrib = torch.cat(stats["contrib"]).to(DT)
    stats["contrib_mean"] = float(contrib.sum() / (W * H))
    stats["contrib_max"] = int(contrib.max())
    return bad, stats


def binned_out_pairs(p, lo, hi, W, H):
    """(pixel, Gaussian) pairs with alpha >= 1/255 that tile binning
    excludes: they show the binning rule is exercised."""
    ys, xs = torch.meshgrid(torch.arange(H, dtype=DT), torch.arange(W, dtype=DT),
                            indexing="ij")
    px, py = xs.reshape(-1) + 0.5, ys.reshape(-1) + 0.5
    tx, ty = (px // TILE).long(), (py // TILE).long()
    m, cn = p["mean2d"].detach(), p["conic"].detach()
    dx = m[None, :, 0] - px[:, None]
    dy = m[None, :, 1] - py[:, None]
    sig = 0.5 * (cn[None, :, 0] * dx * dx + cn[None, :, 2] * dy * dy) \
        + cn[None, :, 1] * dx * dy
    alpha = p["opacity"].detach()[None, :] * torch.exp(-sig)
    binned = ((lo[None, :, 0] <= tx[:, None]) & (tx[:, None] < hi[None, :, 0]) &
              (lo[None, :, 1] <= ty[:, None]) & (ty[:, None] < hi[None, :, 1]))
    return int(((alpha >= MIN_ALPHA) & ~binned & p["valid"][None, :]).sum())


def add_binning_probes(spec, cam, g, count=6):
    """Moves Gaussians 0..count-1 (opaque, isotropic, about 4 px wide) so
    that 3 sqrt(lambda_max) is 0.05 below its ceiling and the right edge of
    the radius box lies 0.1 px left of a tile boundary: the pixels just
    past that boundary see alpha >= 1/255 but are not binned."""
    W, H = cam["width"], cam["height"]
    V = cam["viewmat"]
    with torch.no_grad():
        for i in range(count):
            g["opacity_logits"][i] = 4.0
            ls = math.log(0.23)
            y_target = H * (0.3 + 0.4 * i / max(1, count - 1))
            for _ in range(30):
                g["log_scales"][i] = as_f32(torch.full((3,), ls, dtype=DT))
                one = {k: v[i:i + 1] for k, v in g.items()}
                p = project(cam, one, spec["antialiased"])
                r3 = float(p["r3"][0])
                ls += math.log((math.floor(r3) + 0.95) / r3)
                m = p["mean2d"][0]
                edge = float(m[0] + p["radius"][0])
                k = min(max(1, round(edge / TILE)), (W - 1) // TILE)
                dx = (TILE * k - 0.1) - edge
                dy = y_target - float(m[1])
                z = float(p["depth"][0])
                g["means"][i] = as_f32(g["means"][i] + dx * z / cam["fx"] * V[0, :3]
                                       + dy * z / cam["fy"] * V[1, :3])
                if abs(dx) < 0.01 and abs(r3 - math.floor(r3) - 0.95) < 0.01:
                    break


def make_safe(spec, cam, g, bg):
    """Nudges Gaussians sitting on a discrete threshold until none does."""
    gen = torch.Generator().manual_seed(spec["seed"] + 1000)
    for it in range(200):
        bad, stats = margins(cam, g, bg, spec["antialiased"])
        if not bad:
            stats["nudges"] = it
            with torch.no_grad():
                p = project(cam, g, spec["antialiased"])
                W, H = cam["width"], cam["height"]
                lo, hi = tile_ranges(p["mean2d"], p["radius"], W, H)
                stats["binned_out"] = binned_out_pairs(p, lo, hi, W, H)
            return stats
        idx = torch.tensor(sorted(bad))
        g["opacity_logits"][idx] = as_f32(
            g["opacity_logits"][idx] +
            0.05 * torch.randn(len(idx), generator=gen, dtype=DT))
        g["means"][idx] = as_f32(
            g["means"][idx] + 0.003 * torch.randn(len(idx), 3, generator=gen,
                                                  dtype=DT))
    raise SystemExit("scene %s: could not move off thresholds" % spec["name"])


SCENES = [
    dict(name="basic", seed=11, n=300, channels=3, width=64, height=48,
         antialiased=0, background="none"),
    dict(name="wide_c32", seed=22, n=220, channels=32, width=50, height=37,
         antialiased=0, background="constant", fx=60.0),
    dict(name="antialiased", seed=33, n=300, channels=3, width=64, height=48,
         antialiased=1, background="constant"),
    dict(name="pixel_bg", seed=44, n=260, channels=5, width=64, height=48,
         antialiased=0, background="pixel", fx=80.0, fy=75.0),
]


def check_not_degenerate(spec, stats):
    """A reference scene must exercise every rule it is meant to test."""
    n_pix = spec["width"] * spec["height"]
    need = [
        ("mean contributors per pixel >= 8", stats["contrib_mean"] >= 8),
        ("early-stopped pixels >= 2%", stats["stopped_pixels"] >= 0.02 * n_pix),
        ("clamped alphas >= 10", stats["clamped"] >= 10),
        ("Gaussians straddling a border >= 5", stats["straddling"] >= 5),
        ("culled Gaussians >= 1", stats["offscreen_culled"] >= 1),
        ("visible Gaussians past the Jacobian clamp >= 1",
         stats["jacobian_clamped"] >= 1),
        ("pairs with alpha >= 1/255 excluded by binning >= 10",
         stats["binned_out"] >= 10),
    ]
    if spec["antialiased"]:
        need.append(("compensation > 0.02", stats["min_comp"] > 0.02))
    for what, ok in need:
        if not ok:
            raise SystemExit("scene %s is degenerate: want %s; stats %s" %
                             (spec["name"], what,
                              {k: v for k, v in stats.items() if k != "contrib"}))


def reference(spec):
    cam, g, bg, ups = make_scene(spec)
    add_binning_probes(spec, cam, g)
    stats = make_safe(spec, cam, g, bg)
    check_not_degenerate(spec, stats)
    leaves = {k: v.clone().requires_grad_(True) for k, v in g.items()}
    bgl = bg.clone().requires_grad_(True) if bg is not None else None
    f, a, d, _, _, _ = render(cam, leaves, bgl, spec["antialiased"])
    loss = (f * ups["v_features"]).sum() + (a * ups["v_alpha"]).sum() + \
        (d * ups["v_depth"]).sum()
    loss.backward()
    grads = {k: v.grad for k, v in leaves.items()}
    if bgl is not None:
        grads["background"] = bgl.grad
    return cam, g, bg, ups, (f.detach(), a.detach(), d.detach()), grads, stats


class SceneWriter:
    def __init__(self):
        self.tensors = []

    def add(self, name, t):
        t = torch.as_tensor(t, dtype=torch.float32).contiguous()
        self.tensors.append((name, t))

    def scene(self, k, spec, cam, g, bg, ups, outs, grads, stats):
        s = "s%d." % k
        self.add(s + "camera", [cam["fx"], cam["fy"], cam["cx"], cam["cy"],
                                cam["width"], cam["height"]])
        self.add(s + "viewmat", cam["viewmat"])
        self.add(s + "options", [spec["antialiased"], bg is not None])
        self.add(s + "stats", [stats["visible"], stats["intersections"],
                               stats["pairs"]])
        for key in ("means", "log_scales", "quats", "opacity_logits",
                    "features"):
            self.add(s + key, g[key])
        if bg is not None:
            self.add(s + "background", bg)
        for key, v in ups.items():
            self.add(s + key, v)
        self.add(s + "out_features", outs[0])
        self.add(s + "out_alpha", outs[1])
        self.add(s + "out_depth", outs[2])
        for key, v in grads.items():
            self.add(s + "grad_" + key, v)

    def write(self, path, nscenes):
        with open(path, "wb") as fh:
            fh.write(MAGIC)
            fh.write(struct.pack("<III", VERSION, nscenes, len(self.tensors)))
            for name, t in self.tensors:
                nb = name.encode("ascii")
                fh.write(struct.pack("<I", len(nb)) + nb)
                fh.write(struct.pack("<I", t.dim()))
                fh.write(struct.pack("<%dI" % t.dim(), *t.shape))
                fh.write(t.numpy().astype("<f4").tobytes())


# ---------------------------------------------------------------- self-check

def naive_render(cam, g, bg, aa):
    """Sequential per-pixel loop exactly as the header's pseudo-code."""
    W, H = cam["width"], cam["height"]
    C = g["features"].shape[1]
    with torch.no_grad():
        p = project(cam, g, aa)
        lo, hi = tile_ranges(p["mean2d"], p["radius"], W, H)
        order = [int(i) for i in sort_order(p["depth"]) if p["valid"][i]]
        m, cn = p["mean2d"].tolist(), p["conic"].tolist()
        op, z = p["opacity"].tolist(), p["depth"].tolist()
        lo, hi, feats = lo.tolist(), hi.tolist(), g["features"].tolist()
        bgl = bg.tolist() if bg is not None else None
        out = torch.zeros(C, H, W, dtype=DT)
        alpha = torch.zeros(H, W, dtype=DT)
        depth = torch.zeros(H, W, dtype=DT)
        for y in range(H):
            for x in range(W):
                tx, ty = x // TILE, y // TILE
                T, F, D = 1.0, [0.0] * C, 0.0
                for i in order:
                    if not (lo[i][0] <= tx < hi[i][0] and lo[i][1] <= ty < hi[i][1]):
                        continue
                    dx, dy = m[i][0] - (x + 0.5), m[i][1] - (y + 0.5)
                    a_, b_, c_ = cn[i]
                    sig = 0.5 * (a_ * dx * dx + c_ * dy * dy) + b_ * dx * dy
                    al = min(MAX_ALPHA, op[i] * math.exp(-sig))
                    if sig < 0 or al < MIN_ALPHA:
                        continue
                    if T * (1 - al) <= T_EPS:
                        break
                    for c in range(C):
                        F[c] += feats[i][c] * al * T
                    D += z[i] * al * T
                    T *= 1 - al
                for c in range(C):
                    out[c, y, x] = F[c] + (T * bgl[c][y][x] if bgl is not None else 0.0)
                alpha[y, x] = 1 - T
                depth[y, x] = D
    return out, alpha, depth


def selfcheck():
    ok = True
    spec = dict(name="self", seed=5, n=70, channels=2, width=35, height=21,
                antialiased=1, background="pixel", fx=40.0)
    cam, g, bg, ups = make_scene(spec)
    with torch.no_grad():
        g["opacity_logits"][:10] = 7.0    # exercise the clamp
    _, st = margins(cam, g, bg, 1)
    print("sequential check scene: %d contributing pairs, %d stopped pixels, "
          "%d clamped alphas" % (st["pairs"], st["stopped_pixels"], st["clamped"]))
    ok &= st["stopped_pixels"] > 0 and st["clamped"] > 0
    f, a, d, _, _, _ = render(cam, g, bg, 1)
    nf, na, nd = naive_render(cam, g, bg, 1)
    for what, x, y in (("features", f, nf), ("alpha", a, na), ("depth", d, nd)):
        err = float((x - y).abs().max())
        print("dense vs sequential %-8s max |diff| %.3g" % (what, err))
        ok &= err < 1e-12
    # Autograd vs float64 central differences on a smooth scene: large
    # Gaussians (no 1/255 edge in the image), moderate opacity, no stop.
    spec = dict(name="fd", seed=6, n=5, channels=2, width=20, height=18,
                antialiased=1, background="pixel", fx=30.0)
    cam, g, bg, ups = make_scene(spec)
    with torch.no_grad():
        g["log_scales"][:] = torch.log(torch.tensor([2.0, 1.2, 0.7], dtype=DT))
        g["opacity_logits"][:] = torch.linspace(-1.0, 0.5, 5, dtype=DT)
        g["means"][:] = (torch.tensor([[0.05 * i, -0.03 * i, 0.3 * i]
                                       for i in range(5)], dtype=DT) -
                         cam["viewmat"][:, 3] + torch.tensor([0, 0, 4.0], dtype=DT)) \
            @ cam["viewmat"][:, :3]

    def loss_of(gg, bgv):
        f, a, d, _, _, _ = render(cam, gg, bgv, 1)
        return (f * ups["v_features"]).sum() + (a * ups["v_alpha"]).sum() + \
            (d * ups["v_depth"]).sum()

    leaves = {k: v.clone().requires_grad_(True) for k, v in g.items()}
    bgl = bg.clone().requires_grad_(True)
    loss_of(leaves, bgl).backward()
    h = 1e-6
    worst = 0.0
    for key in list(g.keys()) + ["background"]:
        base = bg if key == "background" else g[key]
        grad = bgl.grad if key == "background" else leaves[key].grad
        flat = base.reshape(-1)
        for j in range(0, flat.numel(), max(1, flat.numel() // 6)):
            vals = []
            for s in (h, -h):
                pert = {k: v.clone() for k, v in g.items()}
                pb = bg.clone()
                tgt = pb if key == "background" else pert[key]
                tgt.view(-1)[j] += s
                with torch.no_grad():
                    vals.append(float(loss_of(pert, pb)))
            fd = (vals[0] - vals[1]) / (2 * h)
            an = float(grad.reshape(-1)[j])
            err = abs(fd - an) / (1e-4 + abs(an) + abs(fd))
            worst = max(worst, err)
            if err > 1e-5:
                print("FD mismatch %s[%d]: autograd %.9g fd %.9g" % (key, j, an, fd))
                ok = False
    print("autograd vs central differences: worst relative error %.3g" % worst)
    print("selfcheck", "ok" if ok else "FAILED")
    return 0 if ok else 1


def main(argv):
    torch.set_num_threads(1)
    if len(argv) == 2 and argv[1] == "--selfcheck":
        return selfcheck()
    if len(argv) != 2:
        print(__doc__, file=sys.stderr)
        return 2
    w = SceneWriter()
    for k, spec in enumerate(SCENES):
        cam, g, bg, ups, outs, grads, stats = reference(spec)
        w.scene(k, spec, cam, g, bg, ups, outs, grads, stats)
        print("scene %d %-12s %2dx%-2d C=%-2d N=%d visible=%d isect=%d "
              "contributors/pixel %.1f (max %d) stopped pixels %d clamped %d "
              "straddling %d (J clamp %d) culled %d binned-out %d nudge rounds %d" %
              (k, spec["name"], spec["width"], spec["height"], spec["channels"],
               spec["n"], stats["visible"], stats["intersections"],
               stats["contrib_mean"], stats["contrib_max"],
               stats["stopped_pixels"], stats["clamped"], stats["straddling"],
               stats["jacobian_clamped"], stats["offscreen_culled"],
               stats["binned_out"],
               stats["nudges"]))
    w.write(argv[1], len(SCENES))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
