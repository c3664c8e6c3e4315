"""One subject behind a proxy that routes on the first frame's subject key
(HAProxy hashing header bytes 12..27 with consistent hashing:
deploy/haproxy, docs/scale-out.md), with the retries that a daemon going
away calls for.

    from gazesplat.routing import SubjectClient
    face = open("face.png", "rb").read()
    with SubjectClient("tcp:proxy.example:7300", face, max_iters=200) as sc:
        sc.fit()
        images = sc.redirect([(10, 0), (0, 20)])  # each target once, in order

The subject's key is chosen here, before the subject exists (by default a
hash of the image and the fit's settings), so that every connection opens
with it: HELLO carries it and the proxy takes the connection to the daemon
that holds (or will hold) the subject. A FIT and its REDIRECTs, each on
their own connection or process, meet the same daemon's cache.

The retry policy (what any client library behind such a proxy must do):

* A lost connection (reset, closed, refused: the daemon died or was
  stopped), BUSY, and the errors of gazesplat.errors.RETRYABLE_CODES
  (ERR_SHUTTING_DOWN, ERR_LOADING, ERR_TOO_MANY_CONNECTIONS, ERR_TIMEOUT)
  are retried on a new connection after a backoff (RetryPolicy: 0.5 s,
  doubling, jittered; BUSY waits its retry_after_ms), up to
  `attempts` tries in all. The proxy's health checks take a dead or
  draining daemon out of the ring within a fraction of the first backoff,
  so the retry lands on the daemon the ring now picks.
* ERR_UNKNOWN_SUBJECT answering a REDIRECT by key means the subject is not
  on that daemon (it moved there, or was evicted): FIT it again with the
  same key and image, then REDIRECT again. This is not an error the caller
  sees.
* A REDIRECT cut after some IMAGEs keeps them: the retry asks only for the
  targets not yet received, so the caller gets every target exactly once
  (no image lost, none twice).
* A socket timeout is not retried (the server may still be working on the
  request), nor are other request errors (bad arguments stay bad).

`errors` lists the retryable errors the last request met (each was
retried); a request that still fails raises the last one.
"""
from __future__ import annotations

import hashlib
import random
import time
from dataclasses import dataclass
from typing import Any, Callable, Dict, List, Optional, Sequence

from . import gazesplat_pb2 as pb
from .client import Client
from .errors import Busy, GazesplatError, retryable
from .protocol import AnglePair, ImageInput

__all__ = ["RetryPolicy", "SubjectClient", "subject_key"]

_ROUTE_TAG = b"gazesplat-route-key-v1\0"


def subject_key(image: ImageInput, **fit_fields: Any) -> bytes:
    """A 16-byte key naming the subject of this image fitted with these
    FIT fields (BLAKE2b-128 of both): the same image asked the same way
    names one subject, on every client."""
    data = image if isinstance(image, (bytes, bytearray, memoryview)) else bytes(image.tobytes())
    h = hashlib.blake2b(_ROUTE_TAG, digest_size=16)
    h.update(bytes(data))
    h.update(repr(sorted(fit_fields.items())).encode())
    return h.digest()


@dataclass
class RetryPolicy:
    """attempts: tries of one request in all (the first included);
    backoff_s: the wait before the first retry, doubled for each next one
    up to max_backoff_s; jitter: each wait is scaled by a random factor in
    [1 - jitter/2, 1 + jitter/2], so that the clients of a dead daemon do
    not come back together."""

    attempts: int = 4
    backoff_s: float = 0.5
    max_backoff_s: float = 5.0
    jitter: float = 0.5

    def delay(self, retry: int, rng: Optional[random.Random] = None) -> float:
        base = min(self.max_backoff_s, self.backoff_s * (2 ** max(0, retry - 1)))
        r = float((rng or random).random())
        return float(base * (1 - self.jitter / 2 + self.jitter * r))


class SubjectClient:
    """The requests of one subject through a subject-hashing proxy (or a
    single daemon: the same calls work there). image: the subject's face
    (as Client.fit takes it); key: its 16-byte subject key (None:
    subject_key(image, **fit_kwargs)); fit_kwargs: Client.fit's options
    (max_iters, finetune_steps, ...). addr, token, timeout: as Client.
    on_retry(exc, delay_s), if given, is called before each retry."""

    def __init__(self, addr: Optional[str], image: ImageInput, key: Optional[bytes] = None,
                 policy: Optional[RetryPolicy] = None, token: Optional[str | bytes] = None,
                 timeout: Optional[float] = 120.0, client_name: str = "python-routing",
                 on_retry: Optional[Callable[[BaseException, float], None]] = None,
                 **fit_kwargs: Any) -> None:
        self.addr = addr
        self.image = image
        self.fit_kwargs = fit_kwargs
        self.key = bytes(key) if key is not None else subject_key(image, **fit_kwargs)
        if len(self.key) != 16:
            raise ValueError("key: want 16 bytes, got %d" % len(self.key))
        self.policy = policy or RetryPolicy()
        self.token = token
        self.timeout = timeout
        self.client_name = client_name
        self.on_retry = on_retry
        self.errors: List[BaseException] = []  # retryable errors of the last request
        self.refits = 0                        # FITs redone after ERR_UNKNOWN_SUBJECT
        self.last_fit: Any = None              # the FitResult of the last FIT sent
        self._conn: Optional[Client] = None
        self._rng = random.Random()

    def __enter__(self) -> "SubjectClient":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def close(self) -> None:
        if self._conn is not None:
            self._conn.close()
            self._conn = None

    def connection(self) -> Client:
        """The open connection (opened with the subject's key in HELLO)."""
        if self._conn is None or self._conn.closed:
            self._conn = Client(self.addr, token=self.token, timeout=self.timeout,
                                client_name=self.client_name, route_key=self.key)
        return self._conn

    def _retry(self, exc: BaseException, tries: int) -> None:
        """Records a failed try; sleeps before the next or raises exc."""
        self.close()
        if not retryable(exc) or tries >= self.policy.attempts:
            raise exc
        self.errors.append(exc)
        delay = (exc.retry_after_ms / 1000.0 if isinstance(exc, Busy)
                 else self.policy.delay(len(self.errors), self._rng))
        if self.on_retry is not None:
            self.on_retry(exc, delay)
        time.sleep(delay)

    def fit(self) -> Any:
        """FIT of the subject under its key (answered from the cache when
        the daemon holds it); returns the FitResult."""
        self.errors = []
        tries = 0
        while True:
            tries += 1
            try:
                self.last_fit = self.connection().fit(self.image, key=self.key, **self.fit_kwargs)
                return self.last_fit
            except Exception as e:  # noqa: BLE001 (sorted by _retry)
                self._retry(e, tries)

    def redirect(self, gaze_deg: Sequence[AnglePair],
                 head_deg: Optional[Sequence[Optional[AnglePair]]] = None,
                 **kwargs: Any) -> List[Any]:
        """REDIRECT of the subject by key to these targets (Client.redirect's
        options in kwargs); returns the ImageResults, one per target in
        target order (index = the target's position), whatever failed on
        the way: a subject the daemon does not hold is fitted again, a
        connection lost midway is resumed with the targets still missing."""
        self.errors = []
        gaze = list(gaze_deg)
        heads = list(head_deg) if head_deg is not None else None
        done: Dict[int, Any] = {}
        tries, need_fit, refits_here = 0, False, 0
        while len(done) < len(gaze):
            todo = [i for i in range(len(gaze)) if i not in done]
            tries += 1
            try:
                c = self.connection()
                if need_fit:
                    self.last_fit = c.fit(self.image, key=self.key, **self.fit_kwargs)
                    need_fit = False
                    self.refits += 1
                stream = c.redirect([gaze[i] for i in todo], subject=self.key,
                                    head_deg=[heads[i] for i in todo] if heads else None, **kwargs)
                for res in stream:
                    i = todo[res.index]
                    res.index = i
                    done[i] = res
            except GazesplatError as e:
                if e.code != pb.ERR_UNKNOWN_SUBJECT or refits_here >= 2:
                    self._retry(e, tries)
                    continue
                # Not held here (moved by the ring, or evicted): fit again.
                need_fit, refits_here, tries = True, refits_here + 1, tries - 1
            except Exception as e:  # noqa: BLE001 (sorted by _retry)
                self._retry(e, tries)
        return [done[i] for i in range(len(gaze))]
