"""asyncio client for gazesplatd: one connection carries several requests
at once (up to the server's max_inflight; more wait their turn), their
replies matched by request id.

    import asyncio
    from gazesplat.aio import AsyncClient

    async def main():
        async with AsyncClient("unix:/run/gazesplat/gazesplatd.sock") as c:
            fits = await asyncio.gather(*(c.fit(face) for face in faces))
            async for res in c.redirect([(10, 0), (0, 20)], subject=fits[0].subject_key):
                ...

redirect() is an async generator: the REDIRECT is sent when iteration
starts. Leaving it early (break, an exception, aclose()) sends CANCEL and
waits for the request's last frame, so the server's in-flight count is
right for the next request; use contextlib.aclosing() to have that happen
at the end of the `async with` block rather than when the generator is
collected. A reply that does not come within `timeout` seconds raises
asyncio.TimeoutError (the request is cancelled; the connection stays
usable).
"""
from __future__ import annotations

import asyncio
import os
from typing import Any, AsyncGenerator, Dict, Optional, Sequence, Tuple

from google.protobuf.message import Message

from . import gazesplat_pb2 as pb
from .errors import Busy, GazesplatError, ProtocolError
from .protocol import (HEADER, VERSION_MAX, VERSION_MIN, ZERO_KEY, AnglePair, Frame, ImageInput,
                       decode, fit_request, live_policy_request, pack_frame, parse_addr,
                       redirect_request, reply_error, unpack_header)

__all__ = ["AsyncClient", "connect"]

FT = pb.FrameType
_CLOSED = object()  # queued to waiters when the connection ends


class _Request:
    __slots__ = ("queue", "done", "abandoned", "slots")

    def __init__(self, slots: asyncio.Semaphore) -> None:
        self.queue: "asyncio.Queue[Any]" = asyncio.Queue()
        self.done: "asyncio.Future[None]" = asyncio.get_running_loop().create_future()
        self.abandoned = False
        self.slots = slots  # released at the request's last frame


class AsyncClient:
    """addr, token, timeout, client_name, retry_busy, route_key: as gazesplat.Client.
    Open with `async with AsyncClient(...)` or `await connect(...)`."""

    def __init__(self, addr: Optional[str] = None, token: Optional[str | bytes] = None,
                 timeout: Optional[float] = 120.0, client_name: str = "python-asyncio",
                 retry_busy: int = 0, route_key: Optional[bytes] = None) -> None:
        if route_key is not None and len(route_key) != len(ZERO_KEY):
            raise ValueError("route_key: want %d bytes, got %d" % (len(ZERO_KEY), len(route_key)))
        self.route_key = bytes(route_key) if route_key is not None else ZERO_KEY
        self.addr = addr
        self.token = token if token is not None else os.environ.get("GAZESPLAT_TOKEN")
        self.timeout = timeout
        self.client_name = client_name
        self.retry_busy = retry_busy
        self.version = VERSION_MIN
        self.server: Any = None
        self._reader: Optional[asyncio.StreamReader] = None
        self._writer: Optional[asyncio.StreamWriter] = None
        self._task: Optional["asyncio.Task[None]"] = None
        self._pending: Dict[int, _Request] = {}
        self._next_id = 1
        self._error: Optional[BaseException] = None
        self._slots: Optional[asyncio.Semaphore] = None

    async def open(self) -> "AsyncClient":
        family, where = parse_addr(self.addr)
        if family == "tcp":
            conn = asyncio.open_connection(*where)
        else:
            conn = asyncio.open_unix_connection(where)
        self._reader, self._writer = await asyncio.wait_for(conn, self.timeout)
        self._task = asyncio.get_running_loop().create_task(self._read_loop())
        self._slots = asyncio.Semaphore(1)  # HELLO alone, then the server's limit
        try:
            msg = pb.Hello(min_version=VERSION_MIN, max_version=VERSION_MAX, client_name=self.client_name)
            if self.token:
                msg.token = self.token.encode() if isinstance(self.token, str) else self.token
            _, ok = await self.call(FT.FRAME_HELLO, msg, FT.FRAME_HELLO_OK, self.route_key)
        except BaseException:
            await self.close()
            raise
        self.version = ok.version
        self.server = ok
        self._slots = asyncio.Semaphore(max(1, ok.limits.max_inflight or 1))
        return self

    async def __aenter__(self) -> "AsyncClient":
        if self._writer is None:
            await self.open()
        return self

    async def __aexit__(self, *exc: Any) -> None:
        await self.close()

    async def close(self) -> None:
        if self._writer is not None:
            self._writer.close()
            try:
                await self._writer.wait_closed()
            except OSError:
                pass
        if self._task is not None:
            self._task.cancel()
            try:
                await self._task
            except (asyncio.CancelledError, Exception):
                pass
            self._task = None
        self._fail(ConnectionError("the connection is closed"))

    # ---- frames ----------------------------------------------------------
    async def _read_loop(self) -> None:
        assert self._reader is not None
        try:
            while True:
                try:
                    head = await self._reader.readexactly(HEADER.size)
                    ftype, n, rid, key = unpack_header(head)
                    f = decode(ftype, rid, key, await self._reader.readexactly(n))
                except asyncio.IncompleteReadError:
                    raise ConnectionError("server closed the connection") from None
                req = self._pending.get(rid)
                if req is None:
                    if rid == 0 and f.type == FT.FRAME_ERROR:
                        # A connection error (ERR_TIMEOUT, ...): the server closes.
                        raise reply_error(f) or ProtocolError("connection error")
                    raise ProtocolError("frame %s for request %d, which is not in flight"
                                        % (FT.Name(f.type), rid))
                final = f.type != FT.FRAME_IMAGE  # a request's every other reply is its last
                if not req.abandoned:
                    req.queue.put_nowait(f)
                if final:
                    del self._pending[rid]
                    if not req.done.done():
                        req.done.set_result(None)
                    req.slots.release()
        except asyncio.CancelledError:
            raise
        except BaseException as e:
            self._fail(e)

    def _fail(self, e: BaseException) -> None:
        """The connection ended: every waiter gets e."""
        if self._error is None:
            self._error = e
        for req in self._pending.values():
            req.queue.put_nowait(_CLOSED)
            if not req.done.done():
                req.done.set_result(None)
        self._pending.clear()
        if self._writer is not None:
            self._writer.close()

    def _dead(self) -> BaseException:
        e = self._error
        if isinstance(e, (GazesplatError, Busy, OSError)):
            return ConnectionError("connection ended: %s" % e)
        return ConnectionError("connection ended: %r" % e) if e else ConnectionError("not connected")

    def _new_id(self) -> int:
        while True:
            rid = self._next_id
            self._next_id = (self._next_id + 1) & 0xFFFFFFFF or 1
            if rid not in self._pending:
                return rid

    async def _send(self, ftype: int, msg: Optional[Message], rid: int, key: bytes) -> None:
        if self._writer is None or self._error is not None:
            raise self._dead()
        self._writer.write(pack_frame(ftype, msg, rid, key, self.version))
        await self._writer.drain()

    async def _start(self, ftype: int, msg: Message, key: bytes) -> Tuple[int, _Request]:
        """Sends a request once a slot is free; returns its id and reply queue."""
        if self._slots is None or self._error is not None:
            raise self._dead()
        slots = self._slots
        await slots.acquire()
        if self._error is not None:
            slots.release()
            raise self._dead()
        rid = self._new_id()
        req = self._pending[rid] = _Request(slots)
        try:
            await self._send(ftype, msg, rid, key)
        except BaseException:
            self._pending.pop(rid, None)
            slots.release()
            raise
        return rid, req

    async def _next(self, rid: int, req: _Request) -> Frame:
        try:
            f = await asyncio.wait_for(req.queue.get(), self.timeout)
        except asyncio.TimeoutError:
            await self._abandon(rid, req, wait=False)
            raise
        if f is _CLOSED:
            raise self._dead()
        return f  # type: ignore[no-any-return]

    async def _abandon(self, rid: int, req: _Request, wait: bool = True) -> None:
        """Cancels an unfinished request; its remaining frames are dropped.
        wait: until its last frame (at most timeout seconds)."""
        if req.done.done():
            return
        req.abandoned = True
        if self._error is None:
            try:
                await self._send(FT.FRAME_CANCEL, pb.Cancel(request_id=rid), self._new_id(), ZERO_KEY)
            except OSError:
                return
        if wait:
            try:
                await asyncio.wait_for(asyncio.shield(req.done), self.timeout)
            except asyncio.TimeoutError:
                pass

    async def call(self, ftype: int, msg: Message, want: int, key: bytes = ZERO_KEY) -> Tuple[bytes, Any]:
        """Sends a request and returns (key, reply); retries BUSY up to
        retry_busy times after the server's retry-after."""
        for attempt in range(self.retry_busy + 1):
            rid, req = await self._start(ftype, msg, key)
            try:
                f = await self._next(rid, req)
            except asyncio.CancelledError:
                await self._abandon(rid, req, wait=False)
                raise
            err = reply_error(f)
            if isinstance(err, Busy) and attempt < self.retry_busy:
                await asyncio.sleep(err.retry_after_ms / 1000.0)
                continue
            if err is not None:
                raise err
            if f.type != want:
                raise ProtocolError("unexpected %s while waiting for %s" % (FT.Name(f.type), FT.Name(want)))
            return f.key, f.message
        raise AssertionError("unreachable")

    # ---- requests ---------------------------------------------------------
    async def health(self, list_subjects: bool = False) -> Any:
        req = pb.HealthRequest(list_subjects=list_subjects)
        return (await self.call(FT.FRAME_HEALTH, req, FT.FRAME_HEALTH_OK))[1]

    async def stats(self) -> Dict[str, int]:
        msg = (await self.call(FT.FRAME_STATS, pb.StatsRequest(), FT.FRAME_STATS_OK))[1]
        return {c.name: c.value for c in msg.counters}

    async def wait_ready(self, timeout: float = 120.0, poll: float = 0.1) -> Any:
        """As Client.wait_ready."""
        loop = asyncio.get_running_loop()
        end = loop.time() + timeout
        while True:
            h = await self.health()
            if h.state == pb.Health.READY:
                return h
            if h.state != pb.Health.LOADING or loop.time() > end:
                raise RuntimeError("server is %s: %s" % (pb.Health.State.Name(h.state), h.detail))
            await asyncio.sleep(poll)

    async def live_policy(self, refit: bool = False, **settings: Any) -> Any:
        req = live_policy_request(refit, settings)
        return (await self.call(FT.FRAME_LIVE_POLICY, req, FT.FRAME_LIVE_POLICY_OK))[1]

    async def live_status(self) -> Any:
        return (await self.call(FT.FRAME_LIVE_STATUS, pb.LiveStatusRequest(), FT.FRAME_LIVE_STATUS_OK))[1]

    async def fit(self, image: ImageInput, gaze_deg: Optional[AnglePair] = None,
                  head_deg: Optional[AnglePair] = None, key: Optional[bytes] = None,
                  max_iters: int = 0, deadline_ms: int = 0, photo: bool = False,
                  finetune_steps: int = 0, finetune_parts: str = "", keep_image: bool = False,
                  finetune_outline_px: int = 0, finetune_mirror: bool = True,
                  finetune_lr: float = 0.0, more_images: Sequence[Any] = ()) -> Any:
        """As Client.fit."""
        req = fit_request(image, gaze_deg, head_deg, max_iters, deadline_ms, photo, finetune_steps,
                          finetune_parts, keep_image, finetune_outline_px, finetune_mirror, finetune_lr,
                          more_images)
        return (await self.call(FT.FRAME_FIT, req, FT.FRAME_FIT_OK, key or ZERO_KEY))[1]

    async def redirect(self, gaze_deg: Sequence[AnglePair], subject: Optional[bytes] = None,
                       image: Optional[ImageInput] = None,
                       head_deg: Optional[Sequence[Optional[AnglePair]]] = None, fmt: str = "png",
                       jpeg_quality: int = 0, deadline_ms: int = 0, max_iters: int = 0,
                       photo: bool = False, paste_back: bool = False, finetune_steps: int = 0,
                       finetune_parts: str = "", transfer: bool = False,
                       finetune_outline_px: int = 0, finetune_mirror: bool = True,
                       finetune_lr: float = 0.0,
                       min_quality: float = 0.0, quality: bool = False) -> AsyncGenerator[Any, None]:
        """As Client.redirect, an async generator of ImageResults. BUSY is
        retried retry_busy times before any image came."""
        req = redirect_request(gaze_deg, subject, image, head_deg, fmt, jpeg_quality, deadline_ms,
                               max_iters, photo, paste_back, finetune_steps, finetune_parts, transfer,
                               finetune_outline_px, finetune_mirror, finetune_lr, min_quality, quality)
        for attempt in range(self.retry_busy + 1):
            rid, r = await self._start(FT.FRAME_REDIRECT, req, subject or ZERO_KEY)
            retry_ms = 0
            try:
                while True:
                    f = await self._next(rid, r)
                    if f.type == FT.FRAME_IMAGE:
                        yield f.message
                        continue
                    if f.type == FT.FRAME_DONE:
                        return
                    err = reply_error(f)
                    if isinstance(err, Busy) and attempt < self.retry_busy:
                        retry_ms = err.retry_after_ms
                        break
                    if err is not None:
                        raise err
                    raise ProtocolError("unexpected %s inside a REDIRECT" % FT.Name(f.type))
            finally:
                # Left early: cancel, and wait for the request's last frame.
                if not r.done.done():
                    await self._abandon(rid, r)
            await asyncio.sleep(retry_ms / 1000.0)

    async def cancel(self, request_id: int) -> None:
        """Asks the server to stop request_id (see Client.cancel)."""
        await self._send(FT.FRAME_CANCEL, pb.Cancel(request_id=request_id), self._new_id(), ZERO_KEY)


async def connect(addr: Optional[str] = None, token: Optional[str | bytes] = None,
                  timeout: Optional[float] = 120.0, client_name: str = "python-asyncio",
                  retry_busy: int = 0) -> AsyncClient:
    """An open AsyncClient (close it with `await client.close()`)."""
    return await AsyncClient(addr, token, timeout, client_name, retry_busy).open()
