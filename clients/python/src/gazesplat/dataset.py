"""A PyTorch IterableDataset of gaze-redirected samples streamed from
gazesplatd (needs the extra [torch]: torch and numpy).

For each source face it fits a subject once per worker (the server caches
the fit) and asks for gaze targets; each sample is a dict

    image            float32 [3, S, S] in [0, 1], the normalized face
    gaze             float32 [2] (pitch, yaw) radians: the target gaze, head frame
    head             float32 [2] (pitch, yaw) radians: the head pose rendered
                     (the target's, else the fitted one), normalized camera
    gaze_head_deg    float32 [2] the target gaze, head frame, degrees
    gaze_camera_deg  float32 [2] the same gaze in the normalized camera frame
                     (R_head applied to it: gazesplat.geometry), degrees
    head_deg         float32 [2] the head pose, degrees
    source           int, index of the source in `sources`
    source_name      str, its path (or a dict source's "name", else "#index")
    subject_key      str, the subject key (hex)
    fit_psnr         float, the subject fit's PSNR on the source, dB
    quality          float, the server's quality score of the render: NaN
                     (the protocol has none yet; a number keeps the field
                     collatable by DataLoader's default_collate)
    epoch            int

Angles follow the ETH-XGaze convention (pitch > 0 up, yaw > 0 toward
image-left); the labels are exact by construction: they are what the
model was asked to render.

    ds = RedirectedGazeDataset(["face0.png", "face1.png"],
                               gaze_targets=[(0, 0), (10, -20), (-10, 20)])
    loader = torch.utils.data.DataLoader(ds, batch_size=16, num_workers=2)
    for epoch in range(10):
        ds.set_epoch(epoch)
        for batch in loader: ...

Each epoch's targets are drawn from (seed, epoch) alone, the same whatever
the number of workers. The epoch's requests (one source, up to `batch`
targets each) are shuffled and dealt to the workers in turn, and each worker
passes its samples through a shuffle buffer, so that a DataLoader batch
mixes sources (shuffle=False: sources in order, targets in order). Each
worker opens its own connection. BUSY replies are retried after the
server's retry-after; a subject the server evicted is fitted again.

transfer=True renders by detail transfer (the source's own skin, hair and
iris, carried to each target through the model's geometry, instead of the
model's smoother render): each source is fitted with keep_image, and a
source whose kept input the server evicted (input_cache_mb) is fitted
again, which keeps it anew (the fit itself is cached).
"""
from __future__ import annotations

import math
import os
import random
import time
from typing import (Any, Callable, Dict, Iterator, List, Mapping, Optional, Sequence, Tuple,
                    Union)

import numpy as np
import torch

from . import gazesplat_pb2 as pb
from .client import Client
from .errors import Busy, GazesplatError
from .geometry import gaze_head_to_camera
from .protocol import AnglePair, image_array

__all__ = ["RedirectedGazeDataset", "Sample"]

DEG = math.pi / 180.0
Sample = Dict[str, Any]
Source = Union[str, "os.PathLike[str]", bytes, bytearray, np.ndarray, Mapping[str, Any]]
Targets = Union[Sequence[AnglePair], Callable[[random.Random], AnglePair]]
HeadTargets = Union[None, AnglePair, Callable[[random.Random], AnglePair]]
# One REDIRECT of an epoch: (source index, gazes, head poses or None).
Item = Tuple[int, List[AnglePair], Optional[List[AnglePair]]]


def _read(src: Any) -> Any:
    if isinstance(src, (bytes, bytearray)):
        return bytes(src)
    if isinstance(src, np.ndarray):
        return src
    with open(src, "rb") as f:
        return f.read()


class RedirectedGazeDataset(torch.utils.data.IterableDataset):  # type: ignore[misc]
    """sources: normalized face images (paths, PNG/JPEG bytes or HxWx3 uint8
    arrays), or dicts {"image": ..., "gaze_deg": (p, y), "head_deg": (p, y),
    "photo": bool, "name": str} with known labels (and per-source kind).
    photo=True: the sources are photos (KIND_PHOTO: the server finds the face
    and normalizes it; needs a server with photo_input). gaze_targets:
    [(pitch, yaw) degrees, head frame], or a callable rng -> (pitch, yaw)
    drawn targets_per_source times per source and epoch. head_targets: None
    (the fitted head pose), one pose for all, or a callable rng -> (pitch,
    yaw). batch: targets per REDIRECT (at most the server's max_targets).
    timeout: seconds a socket operation may wait; deadline_ms: each FIT's
    and REDIRECT's deadline at the server (0: the server's default).
    epochs: epochs per iteration, from the one set_epoch() set.
    shuffle_buffer: samples a worker holds to shuffle (0: none)."""

    def __init__(self, sources: Sequence[Source], gaze_targets: Targets,
                 head_targets: HeadTargets = None, targets_per_source: int = 8,
                 addr: Optional[str] = None, token: Optional[str] = None, fit_iters: int = 0,
                 batch: int = 8, seed: int = 0, epochs: int = 1, transfer: bool = False,
                 photo: bool = False, timeout: Optional[float] = 120.0, deadline_ms: int = 0,
                 shuffle: bool = True, shuffle_buffer: int = 64,
                 client_name: str = "gazesplat-dataset") -> None:
        super().__init__()
        self.sources = list(sources)
        if not self.sources:
            raise ValueError("no sources")
        if batch < 1 or targets_per_source < 1 or epochs < 1:
            raise ValueError("batch, targets_per_source and epochs must be >= 1")
        if not callable(gaze_targets):
            gaze_targets = [(float(g[0]), float(g[1])) for g in gaze_targets]
            if not gaze_targets:
                raise ValueError("no gaze targets")
        if deadline_ms < 0:
            raise ValueError("deadline_ms must be >= 0")
        self.gaze_targets = gaze_targets
        self.head_targets = head_targets
        self.targets_per_source = targets_per_source
        self.addr, self.token = addr, token
        self.fit_iters, self.batch = fit_iters, batch
        self.seed, self.epochs = seed, epochs
        self.epoch = 0
        self.transfer = transfer
        self.photo = photo
        self.timeout, self.deadline_ms = timeout, deadline_ms
        self.shuffle, self.shuffle_buffer = shuffle, shuffle_buffer
        self.client_name = client_name

    # ---- epochs and targets ------------------------------------------------
    def set_epoch(self, epoch: int) -> None:
        """The epoch the next iteration starts at: its targets (when drawn)
        and order are a function of (seed, epoch). Call it before each
        epoch's `iter(loader)` (DataLoader workers copy the dataset when an
        iteration starts; with persistent_workers they do not see it)."""
        self.epoch = int(epoch)

    def __len__(self) -> int:
        per = self.targets_per_source if callable(self.gaze_targets) else len(self.gaze_targets)
        return self.epochs * len(self.sources) * per

    def _targets(self, rng: random.Random) -> Tuple[List[AnglePair], Optional[List[AnglePair]]]:
        if callable(self.gaze_targets):
            gazes = [tuple(self.gaze_targets(rng)) for _ in range(self.targets_per_source)]
        else:
            gazes = [tuple(g) for g in self.gaze_targets]
        heads: Optional[List[AnglePair]]
        if self.head_targets is None:
            heads = None
        elif callable(self.head_targets):
            heads = [tuple(self.head_targets(rng)) for _ in gazes]  # type: ignore[misc]
        else:
            heads = [tuple(self.head_targets)] * len(gazes)  # type: ignore[list-item]
        return gazes, heads  # type: ignore[return-value]

    def epoch_items(self, epoch: int) -> List[Item]:
        """The epoch's REDIRECTs in the order they are dealt to workers."""
        rng = random.Random("gazesplat:%d:%d" % (self.seed, epoch))
        items: List[Item] = []
        for idx in range(len(self.sources)):
            gazes, heads = self._targets(rng)
            for k in range(0, len(gazes), self.batch):
                items.append((idx, gazes[k:k + self.batch], heads[k:k + self.batch] if heads else None))
        if self.shuffle:
            rng.shuffle(items)
        return items

    # ---- sources -----------------------------------------------------------
    def source_name(self, idx: int) -> str:
        src = self.sources[idx]
        if isinstance(src, Mapping):
            if src.get("name"):
                return str(src["name"])
            src = src["image"]
        if isinstance(src, (str, os.PathLike)):
            return os.fspath(src)
        return "#%d" % idx

    def _fit(self, client: Client, src: Source) -> Any:
        if isinstance(src, Mapping):
            return client.fit(_read(src["image"]), gaze_deg=src.get("gaze_deg"),
                              head_deg=src.get("head_deg"), max_iters=self.fit_iters,
                              keep_image=self.transfer, deadline_ms=self.deadline_ms,
                              photo=bool(src.get("photo", self.photo)))
        return client.fit(_read(src), max_iters=self.fit_iters, keep_image=self.transfer,
                          deadline_ms=self.deadline_ms, photo=self.photo)

    # ---- iteration -----------------------------------------------------------
    def __iter__(self) -> Iterator[Sample]:
        info = torch.utils.data.get_worker_info()
        wid, nw = (info.id, info.num_workers) if info else (0, 1)
        with Client(self.addr, token=self.token, timeout=self.timeout, retry_busy=1000,
                    client_name=self.client_name) as client:
            step = max(1, min(self.batch, client.server.limits.max_targets or self.batch))
            fits: Dict[int, Any] = {}
            for epoch in range(self.epoch, self.epoch + self.epochs):
                rng = random.Random("gazesplat:%d:%d:%d/%d" % (self.seed, epoch, wid, nw))
                buf: List[Sample] = []
                for idx, gazes, heads in self.epoch_items(epoch)[wid::nw]:
                    if idx not in fits:
                        fits[idx] = self._fit(client, self.sources[idx])
                    for k in range(0, len(gazes), step):
                        for s in self._render(client, fits[idx], idx, gazes[k:k + step],
                                              heads[k:k + step] if heads else None, epoch):
                            if not self.shuffle or self.shuffle_buffer <= 0:
                                yield s
                                continue
                            buf.append(s)
                            if len(buf) >= self.shuffle_buffer:
                                yield buf.pop(rng.randrange(len(buf)))
                rng.shuffle(buf)
                yield from buf

    def _render(self, client: Client, fit: Any, idx: int, gazes: Sequence[AnglePair],
                heads: Optional[Sequence[AnglePair]], epoch: Optional[int] = None) -> Iterator[Sample]:
        """Renders one REDIRECT for source idx (fitted as `fit`) and yields
        its samples in target order."""
        refit = True  # one new FIT when the server evicted the subject or its kept input
        results: List[Any] = []
        for _ in range(1000):
            try:
                results = list(client.redirect(gazes, subject=fit.subject_key, head_deg=heads,
                                               fmt="raw", transfer=self.transfer,
                                               deadline_ms=self.deadline_ms))
                break
            except Busy as b:
                time.sleep(b.retry_after_ms / 1000.0)
            except GazesplatError as e:
                if not (refit and e.code == pb.ERR_UNKNOWN_SUBJECT):
                    raise
                refit = False
                fit = self._fit(client, self.sources[idx])
        else:
            raise RuntimeError("server stayed busy")
        name, key = self.source_name(idx), bytes(fit.subject_key).hex()
        for r in results:
            img = torch.from_numpy(image_array(r).copy()).permute(2, 0, 1).float() / 255.0
            head = tuple(heads[r.index]) if heads else (fit.head.pitch_deg, fit.head.yaw_deg)
            g = tuple(gazes[r.index])
            cam = gaze_head_to_camera(g, head)
            yield {"image": img,
                   "gaze": torch.tensor([g[0] * DEG, g[1] * DEG], dtype=torch.float32),
                   "head": torch.tensor([head[0] * DEG, head[1] * DEG], dtype=torch.float32),
                   "gaze_head_deg": torch.tensor(g, dtype=torch.float32),
                   "gaze_camera_deg": torch.tensor(cam, dtype=torch.float32),
                   "head_deg": torch.tensor(head, dtype=torch.float32),
                   "source": idx,
                   "source_name": name,
                   "subject_key": key,
                   "fit_psnr": float(fit.psnr),
                   "quality": math.nan,
                   "epoch": self.epoch if epoch is None else epoch}
