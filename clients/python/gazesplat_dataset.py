"""A PyTorch IterableDataset of gaze-redirected samples streamed from
gazesplatd: for each source face it fits a subject once (cached by the
server) and asks for the requested gaze targets, yielding

    {"image": float32 [3, S, S] in [0, 1],
     "gaze":  float32 [2] (pitch, yaw) radians, the target gaze,
     "head":  float32 [2] (pitch, yaw) radians, the target (or fitted) head pose,
     "source": int, index of the source image}

Angles follow the ETH-XGaze convention (pitch > 0 up, yaw > 0 toward
image-left); the labels are exact by construction: they are what the model
was asked to render.

    ds = RedirectedGazeDataset(["face0.png", "face1.png"],
                               gaze_targets=[(0, 0), (10, -20), (-10, 20)])
    loader = torch.utils.data.DataLoader(ds, batch_size=16, num_workers=2)

Each DataLoader worker opens its own connection and takes every n-th
source. BUSY replies are retried after the server's retry-after.

transfer=True renders by detail transfer (the source's own skin, hair and
iris, carried to each target through the model's geometry, instead of the
model's smoother render): each source is fitted with keep_image, and a
source whose kept input the server evicted (input_cache_mb) is fitted
again, which keeps it anew (the fit itself is cached).
"""
import math
import random

import numpy as np
import torch

import gazesplat_client as gc

DEG = math.pi / 180.0


def _read(src):
    if isinstance(src, (bytes, bytearray)):
        return bytes(src)
    if isinstance(src, np.ndarray):
        return src
    with open(src, "rb") as f:
        return f.read()


class RedirectedGazeDataset(torch.utils.data.IterableDataset):
    """sources: normalized face images (paths, PNG/JPEG bytes or HxWx3 uint8
    arrays), or dicts {"image": ..., "gaze_deg": (p, y), "head_deg": (p, y)}
    with known labels. gaze_targets: [(pitch, yaw) degrees], or a callable
    rng -> (pitch, yaw) drawn targets_per_source times per source.
    head_targets: None (the fitted head pose), one pose for all, or a
    callable rng -> (pitch, yaw)."""

    def __init__(self, sources, gaze_targets, head_targets=None, targets_per_source=8,
                 addr=None, token=None, fit_iters=0, batch=8, seed=0, epochs=1, transfer=False):
        super().__init__()
        self.sources = list(sources)
        self.gaze_targets = gaze_targets
        self.head_targets = head_targets
        self.targets_per_source = targets_per_source
        self.addr, self.token = addr, token
        self.fit_iters, self.batch = fit_iters, batch
        self.seed, self.epochs = seed, epochs
        self.transfer = transfer

    def _targets(self, rng):
        if callable(self.gaze_targets):
            gazes = [self.gaze_targets(rng) for _ in range(self.targets_per_source)]
        else:
            gazes = list(self.gaze_targets)
        if self.head_targets is None:
            heads = None
        elif callable(self.head_targets):
            heads = [self.head_targets(rng) for _ in gazes]
        else:
            heads = [tuple(self.head_targets)] * len(gazes)
        return gazes, heads

    def _fit(self, client, src):
        if isinstance(src, dict):
            return client.fit(_read(src["image"]), gaze_deg=src.get("gaze_deg"),
                              head_deg=src.get("head_deg"), max_iters=self.fit_iters,
                              keep_image=self.transfer)
        return client.fit(_read(src), max_iters=self.fit_iters, keep_image=self.transfer)

    def __iter__(self):
        info = torch.utils.data.get_worker_info()
        wid, nw = (info.id, info.num_workers) if info else (0, 1)
        rng = random.Random(self.seed * 1000003 + wid)
        with gc.Client(self.addr, token=self.token, retry_busy=1000) as client:
            step = max(1, min(self.batch, client.server.limits.max_targets or self.batch))
            keys = {}
            for _epoch in range(self.epochs):
                for idx in range(wid, len(self.sources), nw):
                    if idx not in keys:
                        keys[idx] = self._fit(client, self.sources[idx])
                    fit = keys[idx]
                    gazes, heads = self._targets(rng)
                    for k in range(0, len(gazes), step):
                        yield from self._render(client, fit, idx, gazes[k:k + step],
                                                heads[k:k + step] if heads else None)

    def _render(self, client, fit, idx, gazes, heads):
        refit = self.transfer  # one new FIT when the kept input was evicted
        for _ in range(1000):
            try:
                results = list(client.redirect(gazes, subject=fit.subject_key, head_deg=heads,
                                               fmt="raw", transfer=self.transfer))
                break
            except gc.Busy as b:
                import time
                time.sleep(b.retry_after_ms / 1000.0)
            except gc.GazesplatError as e:
                if not (refit and e.code == gc.pb.ERR_UNKNOWN_SUBJECT):
                    raise
                refit = False
                self._fit(client, self.sources[idx])
        else:
            raise RuntimeError("server stayed busy")
        for r in results:
            img = torch.from_numpy(gc.image_array(r).copy()).permute(2, 0, 1).float() / 255.0
            head = heads[r.index] if heads else (fit.head.pitch_deg, fit.head.yaw_deg)
            g = gazes[r.index]
            yield {"image": img,
                   "gaze": torch.tensor([g[0] * DEG, g[1] * DEG], dtype=torch.float32),
                   "head": torch.tensor([head[0] * DEG, head[1] * DEG], dtype=torch.float32),
                   "source": idx}
