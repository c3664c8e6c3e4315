"""Blocking client for gazesplatd (proto/PROTOCOL.md): one connection, one
request at a time.

    from gazesplat import Client
    with Client("unix:/run/gazesplat/gazesplatd.sock") as c:
        print(c.health().state)
        fit = c.fit(open("face.png", "rb").read())
        for res in c.redirect([(10, 0), (0, 20)], subject=fit.subject_key):
            open(f"out_{res.index}.png", "wb").write(res.image.data)

A REDIRECT streams one IMAGE frame per target; redirect() returns a
generator over them. Stopping early (break, close(), or dropping the
generator) cancels the rest: the client sends CANCEL and reads the
request's remaining frames up to its last, so the connection serves the
next request. A request made while a redirect is still open settles that
redirect the same way first.
"""
from __future__ import annotations

import os
import socket
import time
from typing import Any, Dict, Generator, Optional, Sequence, Tuple

from google.protobuf.message import Message

from . import gazesplat_pb2 as pb
from .errors import Busy, GazesplatError, ProtocolError
from .protocol import (HEADER, MAGIC, MESSAGES, VERSION_MAX, VERSION_MIN, ZERO_KEY, AnglePair,
                       Frame, ImageInput, angles, decode, fit_request, image_array, image_message,
                       live_policy_request, pack_frame, parse_addr, redirect_request, reply_error,
                       unpack_header)

__all__ = ["Client", "GazesplatError", "Busy", "ProtocolError", "pack_frame", "image_array",
           "pb", "FT", "HEADER", "MAGIC", "MESSAGES", "VERSION_MIN", "VERSION_MAX", "ZERO_KEY"]

FT = pb.FrameType
_FINAL = (FT.FRAME_DONE, FT.FRAME_ERROR, FT.FRAME_BUSY)

# Compatibility with the module's older private helpers.
_image = image_message
_angles = angles


class Client:
    """One connection to gazesplatd; not thread-safe (use one per thread).

    addr: "unix:PATH", a plain PATH or "tcp:HOST:PORT" (None:
    $GAZESPLAT_ADDR, else /run/gazesplat/gazesplatd.sock). token: the shared
    secret of a TCP server (None: $GAZESPLAT_TOKEN). timeout: seconds any
    one socket operation may wait (a fit or render longer than this raises
    socket.timeout; the connection is then closed). retry_busy: how many
    times call() retries a BUSY reply after the server's retry-after.
    route_key: 16 bytes sent as HELLO's subject key, so that a proxy that
    hashes the first frame's key (docs/scale-out.md) takes this connection
    to the daemon of that subject; use the connection for that subject only
    (gazesplat.routing.SubjectClient does this, with retries)."""

    def __init__(self, addr: Optional[str] = None, token: Optional[str | bytes] = None,
                 timeout: Optional[float] = 120.0, client_name: str = "python",
                 retry_busy: int = 0, route_key: Optional[bytes] = None) -> None:
        token = token if token is not None else os.environ.get("GAZESPLAT_TOKEN")
        if route_key is not None and len(route_key) != len(ZERO_KEY):
            raise ValueError("route_key: want %d bytes, got %d" % (len(ZERO_KEY), len(route_key)))
        self.route_key = bytes(route_key) if route_key is not None else ZERO_KEY
        self.timeout = timeout
        self.retry_busy = retry_busy
        self._next_id = 1
        self._buf = bytearray()
        self._open: Optional[int] = None       # request id of an unfinished REDIRECT
        self._cancelled = False                 # CANCEL already sent for it
        family, where = parse_addr(addr)
        if family == "tcp":
            self.sock = socket.create_connection(where, timeout=timeout)
        else:
            self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            self.sock.settimeout(timeout)
            try:
                self.sock.connect(where)
            except OSError:
                self.sock.close()
                raise
        self.version = VERSION_MIN
        try:
            self.server = self.hello(client_name, token)
        except BaseException:
            self.sock.close()
            raise

    def __enter__(self) -> "Client":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def close(self) -> None:
        self._open = None
        self.sock.close()

    @property
    def closed(self) -> bool:
        return self.sock.fileno() < 0

    # ---- frames ----------------------------------------------------------
    def new_id(self) -> int:
        rid = self._next_id
        self._next_id = (self._next_id + 1) & 0xFFFFFFFF or 1
        return rid

    def send(self, ftype: int, msg: Optional[Message] = None, request_id: int = 0,
             key: bytes = ZERO_KEY) -> None:
        if self.closed:
            raise ConnectionError("the connection is closed")
        self.sock.sendall(pack_frame(ftype, msg, request_id, key, self.version))

    def _read(self, n: int) -> bytes:
        while len(self._buf) < n:
            chunk = self.sock.recv(max(65536, n - len(self._buf)))
            if not chunk:
                raise ConnectionError("server closed the connection")
            self._buf += chunk
        out = bytes(self._buf[:n])
        del self._buf[:n]
        return out

    def recv(self) -> Frame:
        """Next frame as (type, request_id, key, message)."""
        ftype, n, rid, key = unpack_header(self._read(HEADER.size))
        return decode(ftype, rid, key, self._read(n))

    def _expect(self, want: int, request_id: int) -> Tuple[bytes, Any]:
        f = self.recv()
        if f.request_id != request_id:
            raise ProtocolError("reply for request %d while waiting for %d" % (f.request_id, request_id))
        err = reply_error(f)
        if err is not None:
            raise err
        if f.type != want:
            raise ProtocolError("unexpected %s while waiting for %s" % (FT.Name(f.type), FT.Name(want)))
        return f.key, f.message

    def call(self, ftype: int, msg: Message, want: int, key: bytes = ZERO_KEY) -> Tuple[bytes, Any]:
        """Sends a request and returns (key, reply); retries BUSY up to
        retry_busy times after the server's retry-after."""
        self._settle()
        for attempt in range(self.retry_busy + 1):
            rid = self.new_id()
            try:
                self.send(ftype, msg, rid, key)
                return self._expect(want, rid)
            except Busy as b:
                if attempt == self.retry_busy:
                    raise
                time.sleep(b.retry_after_ms / 1000.0)
            except OSError:
                # A timeout or a broken socket: the reply may still come,
                # so the connection cannot serve another request.
                self._broken()
                raise
        raise AssertionError("unreachable")

    # ---- requests ---------------------------------------------------------
    def hello(self, client_name: str = "python", token: Optional[str | bytes] = None) -> Any:
        msg = pb.Hello(min_version=VERSION_MIN, max_version=VERSION_MAX, client_name=client_name)
        if token:
            msg.token = token.encode() if isinstance(token, str) else token
        _, ok = self.call(FT.FRAME_HELLO, msg, FT.FRAME_HELLO_OK, self.route_key)
        self.version = ok.version
        return ok

    def health(self, list_subjects: bool = False) -> Any:
        """The Health message (state, detail, queue, model_id, the subjects
        held: their count and digest; list_subjects: their keys too)."""
        req = pb.HealthRequest(list_subjects=list_subjects)
        return self.call(FT.FRAME_HEALTH, req, FT.FRAME_HEALTH_OK)[1]

    def stats(self) -> Dict[str, int]:
        """The server's counters by name."""
        msg = self.call(FT.FRAME_STATS, pb.StatsRequest(), FT.FRAME_STATS_OK)[1]
        return {c.name: c.value for c in msg.counters}

    def wait_ready(self, timeout: float = 120.0, poll: float = 0.1) -> Any:
        """Polls HEALTH while the model loads; returns the READY Health, or
        raises RuntimeError with the server's state and detail."""
        end = time.monotonic() + timeout
        while True:
            h = self.health()
            if h.state == pb.Health.READY:
                return h
            if h.state != pb.Health.LOADING or time.monotonic() > end:
                raise RuntimeError("server is %s: %s" % (pb.Health.State.Name(h.state), h.detail))
            time.sleep(poll)

    def live_policy(self, refit: bool = False, **settings: Any) -> Any:
        """Reads (no arguments) or changes the live eye-contact policy:
        live_policy(strength=0.5, enabled=False). All settings apply or none
        (GazesplatError ERR_INVALID_ARGUMENT). Returns the LivePolicy in force."""
        req = live_policy_request(refit, settings)
        return self.call(FT.FRAME_LIVE_POLICY, req, FT.FRAME_LIVE_POLICY_OK)[1]

    def live_status(self) -> Any:
        return self.call(FT.FRAME_LIVE_STATUS, pb.LiveStatusRequest(), FT.FRAME_LIVE_STATUS_OK)[1]

    def fit(self, image: ImageInput, gaze_deg: Optional[AnglePair] = None,
            head_deg: Optional[AnglePair] = None, key: Optional[bytes] = None, max_iters: int = 0,
            deadline_ms: int = 0, photo: bool = False, finetune_steps: int = 0,
            finetune_parts: str = "", keep_image: bool = False, finetune_outline_px: int = 0,
            finetune_mirror: bool = True, finetune_lr: float = 0.0,
            more_images: Sequence[Any] = ()) -> Any:
        """Fits a subject to a normalized face (PNG/JPEG bytes or HxWx3
        uint8 array; photo=True: any photo, the server finds and normalizes
        the face); returns the FitResult (subject_key, labels, quality).
        finetune_steps > 0: the server then fine-tunes a copy of the model
        on the image (finetune_parts: "face,geometry" by default) and the subject
        renders with it; finetune_outline_px (0..8) keeps its colours from
        learning near the model's outline (fewer background-coloured patches
        at other head poses); finetune_mirror=False fits the input alone, not
        also its mirror image; finetune_lr in (0, 1] is Adam's base rate (0:
        the server's finetune_lr, 0.004 unless configured; the result's
        finetune_lr says which ran). keep_image: the server keeps the (normalized)
        input with the subject, so that redirect(subject=..., transfer=True)
        works by key. more_images: other images of the same person (at most
        15; each an image, or a tuple (image, gaze_deg, head_deg) with its
        own labels), fitted with `image` as one subject: one identity (and
        one fine-tuning), the subject rendering from `image`'s expression,
        lights and head pose; the result's image_results say what the fit
        made of each image (docs/subjects.md)."""
        req = fit_request(image, gaze_deg, head_deg, max_iters, deadline_ms, photo, finetune_steps,
                          finetune_parts, keep_image, finetune_outline_px, finetune_mirror, finetune_lr,
                          more_images)
        return self.call(FT.FRAME_FIT, req, FT.FRAME_FIT_OK, key or ZERO_KEY)[1]

    def redirect(self, gaze_deg: Sequence[AnglePair], subject: Optional[bytes] = None,
                 image: Optional[ImageInput] = None,
                 head_deg: Optional[Sequence[Optional[AnglePair]]] = None, fmt: str = "png",
                 jpeg_quality: int = 0, deadline_ms: int = 0, max_iters: int = 0,
                 photo: bool = False, paste_back: bool = False, finetune_steps: int = 0,
                 finetune_parts: str = "", transfer: bool = False, finetune_outline_px: int = 0,
                 finetune_mirror: bool = True, finetune_lr: float = 0.0,
                 min_quality: float = 0.0, quality: bool = False) -> Generator[Any, None, None]:
        """Sends one REDIRECT now and returns a generator of its ImageResults
        (index, image, target) as the server streams them; it ends at DONE
        and raises GazesplatError/Busy for an ERROR/BUSY reply.
        gaze_deg: [(pitch, yaw), ...] in the head frame; head_deg: None or
        one pose (or None) per target. subject: a FIT's subject_key; or
        image: an inline source (photo=True: any photo, the server finds the
        face; paste_back: return the photo with the redirected face blended
        in). fmt: "png", "jpeg" or "raw" (image_array() decodes raw).
        finetune_steps, finetune_parts, finetune_outline_px, finetune_mirror,
        finetune_lr: for an inline image, as fit(). transfer: keep the
        input's own detail (detail transfer); by subject key it needs a fit
        with keep_image=True.
        quality=True: each ImageResult carries `quality` when the server can
        measure it (gaze-only targets, the input at hand: inline or kept;
        28 ms an image at 256 px, about 5 gaze-sweep renders): score 0..1,
        the gaze asked and seen by the irises, iris delta E, eye speckle,
        reason (docs/face.md, "Redirect quality"). min_quality in [0, 1]:
        images scoring lower come back with dropped=True and no image (it
        implies quality=True).
        Stopping early cancels the rest of the request (see the module)."""
        req = redirect_request(gaze_deg, subject, image, head_deg, fmt, jpeg_quality, deadline_ms,
                               max_iters, photo, paste_back, finetune_steps, finetune_parts, transfer,
                               finetune_outline_px, finetune_mirror, finetune_lr, min_quality, quality)
        self._settle()
        rid = self.new_id()
        self.send(FT.FRAME_REDIRECT, req, rid, subject or ZERO_KEY)
        return self.images(rid)

    def images(self, rid: int) -> Generator[Any, None, None]:
        """The ImageResults of REDIRECT request rid, sent with send(): as
        redirect()'s generator (the request counts as open from now on)."""
        self._settle()
        self._open, self._cancelled = rid, False
        return self._stream(rid)

    _images = images  # the name older scripts use

    def _stream(self, rid: int) -> Generator[Any, None, None]:
        try:
            while True:
                if self._open != rid:
                    raise RuntimeError("redirect %d was cancelled: a later request on this connection "
                                       "ended it (finish one redirect before starting another)" % rid)
                try:
                    f = self._next_of(rid)
                except OSError:
                    self._broken()
                    raise
                if f.type == FT.FRAME_IMAGE:
                    yield f.message
                    continue
                self._open = None
                if f.type == FT.FRAME_DONE:
                    return
                err = reply_error(f)
                if err is not None:
                    raise err
                raise ProtocolError("unexpected %s inside a REDIRECT" % FT.Name(f.type))
        finally:
            # Stopped early (break, close(), garbage collection, or an
            # exception in the caller's loop): cancel and drain.
            if self._open == rid:
                self._settle()

    def _next_of(self, rid: int) -> Frame:
        f = self.recv()
        if f.request_id != rid:
            self._broken()
            raise ProtocolError("frame for request %d inside request %d" % (f.request_id, rid))
        return f

    def _settle(self) -> None:
        """Ends the open REDIRECT, if any: CANCEL, then its frames up to the
        last (DONE, ERROR or BUSY) are read and dropped. On a socket error
        the connection is closed (its state is unknown)."""
        rid = self._open
        if rid is None:
            return
        try:
            if not self._cancelled:
                self._cancelled = True
                self.cancel(rid)
            while self._next_of(rid).type not in _FINAL:
                pass
            self._open = None
        except BaseException:
            self._broken()
            raise

    def _broken(self) -> None:
        self._open = None
        try:
            self.sock.close()
        except OSError:
            pass

    def cancel(self, request_id: int) -> None:
        """Asks the server to stop request_id; its last frame is ERROR
        ERR_CANCELLED (nothing is sent for an unknown or finished id)."""
        self.send(FT.FRAME_CANCEL, pb.Cancel(request_id=request_id), self.new_id())
