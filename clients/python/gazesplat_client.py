"""Python client for gazesplatd (proto/PROTOCOL.md).

Pure Python: the standard library's socket and struct, plus Debian's
python3-protobuf for the messages. The message classes (gazesplat_pb2) are
generated from proto/gazesplat.proto, never committed; they are looked for
in $GAZESPLAT_PB2_DIR, next to this file, in the build tree's python/
directory, and otherwise generated with protoc into a cache directory.

    from gazesplat_client import Client
    with Client("unix:/run/gazesplat/gazesplatd.sock") as c:
        print(c.health().state)
        fit = c.fit(open("face.png", "rb").read())
        for res in c.redirect(subject=fit.subject_key, gaze_deg=[(10, 0), (0, 20)]):
            open(f"out_{res.index}.png", "wb").write(res.image.data)
"""
import importlib
import os
import socket
import struct
import subprocess
import sys
import tempfile
import time

HEADER = struct.Struct("<4sHHI16sI")
MAGIC = b"GAZE"
VERSION_MIN = VERSION_MAX = 1
ZERO_KEY = b"\0" * 16


def _load_pb2():
    here = os.path.dirname(os.path.abspath(__file__))
    candidates = [os.environ.get("GAZESPLAT_PB2_DIR"), here,
                  os.path.join(here, "..", "..", "build", "python")]
    for d in candidates:
        if d and os.path.exists(os.path.join(d, "gazesplat_pb2.py")):
            sys.path.insert(0, d)
            try:
                return importlib.import_module("gazesplat_pb2")
            finally:
                sys.path.remove(d)
    proto = os.path.join(here, "..", "..", "proto", "gazesplat.proto")
    if not os.path.exists(proto):
        raise ImportError("gazesplat_pb2 not found: set GAZESPLAT_PB2_DIR")
    out = os.path.join(tempfile.gettempdir(), "gazesplat_pb2_%d" % os.getuid())
    os.makedirs(out, exist_ok=True)
    subprocess.run(["protoc", "--python_out=" + out, "-I", os.path.dirname(proto), proto], check=True)
    sys.path.insert(0, out)
    try:
        return importlib.import_module("gazesplat_pb2")
    finally:
        sys.path.remove(out)


pb = _load_pb2()
FT = pb.FrameType

# Frame type -> message class of its payload.
MESSAGES = {
    FT.FRAME_HELLO: pb.Hello, FT.FRAME_HELLO_OK: pb.HelloOk,
    FT.FRAME_HEALTH: pb.HealthRequest, FT.FRAME_HEALTH_OK: pb.Health,
    FT.FRAME_STATS: pb.StatsRequest, FT.FRAME_STATS_OK: pb.Stats,
    FT.FRAME_FIT: pb.FitRequest, FT.FRAME_FIT_OK: pb.FitResult,
    FT.FRAME_REDIRECT: pb.RedirectRequest, FT.FRAME_IMAGE: pb.ImageResult,
    FT.FRAME_DONE: pb.Done, FT.FRAME_CANCEL: pb.Cancel, FT.FRAME_ERROR: pb.Error,
    FT.FRAME_BUSY: pb.Busy, FT.FRAME_SLEEP: pb.Sleep, FT.FRAME_SLEEP_OK: pb.Done,
    FT.FRAME_LIVE_POLICY: pb.LivePolicyRequest, FT.FRAME_LIVE_POLICY_OK: pb.LivePolicy,
    FT.FRAME_LIVE_STATUS: pb.LiveStatusRequest, FT.FRAME_LIVE_STATUS_OK: pb.LiveStatus,
}


class GazesplatError(Exception):
    """An ERROR frame from the server."""

    def __init__(self, err):
        self.code = err.code
        self.name = pb.ErrorCode.Name(err.code) if err.code in pb.ErrorCode.values() else str(err.code)
        self.message = err.message
        self.request_id = err.request_id
        super().__init__("%s: %s" % (self.name, self.message))


class Busy(Exception):
    """A BUSY frame: the server's queue is full."""

    def __init__(self, busy):
        self.retry_after_ms = busy.retry_after_ms
        self.queue_length = busy.queue_length
        super().__init__("server busy, retry after %d ms" % busy.retry_after_ms)


def pack_frame(ftype, msg=None, request_id=0, key=ZERO_KEY, version=1):
    """Header + payload bytes of one frame."""
    body = msg.SerializeToString() if msg is not None else b""
    return HEADER.pack(MAGIC, version, ftype, len(body), bytes(key), request_id) + body


def _image(image, kind=pb.KIND_NORMALIZED_FACE):
    """An Image message from PNG/JPEG bytes or an HxWx3 uint8 array."""
    if isinstance(image, (bytes, bytearray, memoryview)):
        data = bytes(image)
        if data[:8] == b"\x89PNG\r\n\x1a\n":
            fmt = pb.FORMAT_PNG
        elif data[:3] == b"\xff\xd8\xff":
            fmt = pb.FORMAT_JPEG
        else:
            raise ValueError("image bytes are neither PNG nor JPEG")
        return pb.Image(format=fmt, data=data, kind=kind)
    h, w, c = image.shape
    if c != 3 or str(image.dtype) != "uint8":
        raise ValueError("array images must be HxWx3 uint8")
    return pb.Image(format=pb.FORMAT_RAW_RGB8, data=image.tobytes(), width=w, height=h,
                    stride=3 * w, kind=kind)


def _angles(pair):
    return None if pair is None else pb.Angles(pitch_deg=float(pair[0]), yaw_deg=float(pair[1]))


class Client:
    """One connection to gazesplatd; not thread-safe (use one per thread)."""

    def __init__(self, addr=None, token=None, timeout=120.0, client_name="python",
                 retry_busy=0):
        addr = addr or os.environ.get("GAZESPLAT_ADDR", "/run/gazesplat/gazesplatd.sock")
        token = token if token is not None else os.environ.get("GAZESPLAT_TOKEN")
        self.timeout = timeout
        self.retry_busy = retry_busy
        self._next_id = 1
        self._buf = b""
        if addr.startswith("tcp:"):
            host, port = addr[4:].rsplit(":", 1)
            self.sock = socket.create_connection((host.strip("[]"), int(port)), timeout=timeout)
        else:
            path = addr[5:] if addr.startswith("unix:") else addr
            self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            self.sock.settimeout(timeout)
            self.sock.connect(path)
        self.version = VERSION_MIN
        self.server = self.hello(client_name, token)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self):
        self.sock.close()

    # ---- frames ----------------------------------------------------------
    def new_id(self):
        rid = self._next_id
        self._next_id = (self._next_id + 1) & 0xFFFFFFFF or 1
        return rid

    def send(self, ftype, msg=None, request_id=0, key=ZERO_KEY):
        self.sock.sendall(pack_frame(ftype, msg, request_id, key, self.version))

    def _read(self, n):
        while len(self._buf) < n:
            chunk = self.sock.recv(max(65536, n - len(self._buf)))
            if not chunk:
                raise ConnectionError("server closed the connection")
            self._buf += chunk
        out, self._buf = self._buf[:n], self._buf[n:]
        return out

    def recv(self):
        """Next frame as (type, request_id, key, message)."""
        magic, _ver, ftype, n, key, rid = HEADER.unpack(self._read(HEADER.size))
        if magic != MAGIC:
            raise ConnectionError("bad magic from server: %r" % magic)
        cls = MESSAGES.get(ftype)
        if cls is None:
            raise ConnectionError("unknown frame type %d from server" % ftype)
        return ftype, rid, key, cls.FromString(self._read(n))

    def _expect(self, want, request_id):
        ftype, rid, key, msg = self.recv()
        if rid != request_id:
            raise ConnectionError("reply for request %d while waiting for %d" % (rid, request_id))
        if ftype == FT.FRAME_ERROR:
            raise GazesplatError(msg)
        if ftype == FT.FRAME_BUSY:
            raise Busy(msg)
        if ftype != want:
            raise ConnectionError("unexpected %s" % FT.Name(ftype))
        return key, msg

    def call(self, ftype, msg, want, key=ZERO_KEY):
        """Sends a request and returns (key, reply); retries BUSY up to
        retry_busy times after the server's retry-after."""
        for attempt in range(self.retry_busy + 1):
            rid = self.new_id()
            self.send(ftype, msg, rid, key)
            try:
                return self._expect(want, rid)
            except Busy as b:
                if attempt == self.retry_busy:
                    raise
                time.sleep(b.retry_after_ms / 1000.0)
        raise AssertionError("unreachable")

    # ---- requests ---------------------------------------------------------
    def hello(self, client_name="python", token=None):
        msg = pb.Hello(min_version=VERSION_MIN, max_version=VERSION_MAX, client_name=client_name)
        if token:
            msg.token = token.encode() if isinstance(token, str) else token
        _, ok = self.call(FT.FRAME_HELLO, msg, FT.FRAME_HELLO_OK)
        self.version = ok.version
        return ok

    def health(self):
        return self.call(FT.FRAME_HEALTH, pb.HealthRequest(), FT.FRAME_HEALTH_OK)[1]

    def stats(self):
        msg = self.call(FT.FRAME_STATS, pb.StatsRequest(), FT.FRAME_STATS_OK)[1]
        return {c.name: c.value for c in msg.counters}

    def live_policy(self, refit=False, **settings):
        """Reads (no arguments) or changes the live eye-contact policy:
        live_policy(strength=0.5, enabled=False). All settings apply or none
        (GazesplatError ERR_INVALID_ARGUMENT). Returns the LivePolicy in force."""
        req = pb.LivePolicyRequest(refit=refit)
        for k, v in settings.items():
            if isinstance(v, bool):
                v = "yes" if v else "no"
            req.set.add(key=k, value=str(v))
        return self.call(FT.FRAME_LIVE_POLICY, req, FT.FRAME_LIVE_POLICY_OK)[1]

    def live_status(self):
        return self.call(FT.FRAME_LIVE_STATUS, pb.LiveStatusRequest(), FT.FRAME_LIVE_STATUS_OK)[1]

    def fit(self, image, gaze_deg=None, head_deg=None, key=None, max_iters=0, deadline_ms=0,
            photo=False, finetune_steps=0, finetune_parts="", keep_image=False,
            finetune_outline_px=0, finetune_mirror=True, finetune_lr=0.0):
        """Fits a subject to a normalized face (PNG/JPEG bytes or HxWx3
        uint8 array); returns the FitResult (subject_key, labels, quality).
        finetune_steps > 0: the server then fine-tunes a copy of the model
        on the image (finetune_parts: "face,geometry" by default) and the subject
        renders with it; finetune_outline_px (0..8) keeps its colours from
        learning near the model's outline (fewer background-coloured patches
        at other head poses); finetune_mirror=False fits the input alone, not
        also its mirror image; finetune_lr in (0, 1] is Adam's base rate (0:
        the server's finetune_lr, 0.004 unless configured; the result's
        finetune_lr says which ran). keep_image: the server keeps the (normalized)
        input with the subject, so that redirect(subject=..., transfer=True)
        works by key."""
        kind = pb.KIND_PHOTO if photo else pb.KIND_NORMALIZED_FACE
        req = pb.FitRequest(image=_image(image, kind), max_iters=max_iters, deadline_ms=deadline_ms,
                            finetune_steps=finetune_steps, finetune_parts=finetune_parts,
                            keep_image=keep_image, finetune_outline_px=finetune_outline_px,
                            finetune_no_mirror=not finetune_mirror, finetune_lr=finetune_lr)
        if gaze_deg is not None:
            req.gaze.CopyFrom(_angles(gaze_deg))
        if head_deg is not None:
            req.head.CopyFrom(_angles(head_deg))
        return self.call(FT.FRAME_FIT, req, FT.FRAME_FIT_OK, key or ZERO_KEY)[1]

    def redirect(self, gaze_deg, subject=None, image=None, head_deg=None, fmt="png",
                 jpeg_quality=0, deadline_ms=0, max_iters=0, photo=False, paste_back=False,
                 finetune_steps=0, finetune_parts="", transfer=False, finetune_outline_px=0,
                 finetune_mirror=True, finetune_lr=0.0):
        """Yields one ImageResult per target as the server streams them.
        gaze_deg: [(pitch, yaw), ...]; head_deg: None or one pose per target.
        photo: the image is a photo (the server finds the face); paste_back:
        return the photo with the redirected face blended in. finetune_steps,
        finetune_parts, finetune_outline_px, finetune_mirror, finetune_lr: for an inline
        image, as fit().
        transfer: keep the
        input's own detail (detail transfer); by subject key it needs a fit
        with keep_image=True."""
        if (subject is None) == (image is None):
            raise ValueError("give exactly one of subject and image")
        req = pb.RedirectRequest(
            output_format={"png": pb.FORMAT_PNG, "jpeg": pb.FORMAT_JPEG, "raw": pb.FORMAT_RAW_RGB8}[fmt],
            jpeg_quality=jpeg_quality, deadline_ms=deadline_ms, max_iters=max_iters,
            finetune_steps=finetune_steps, finetune_parts=finetune_parts, transfer=transfer,
            finetune_outline_px=finetune_outline_px, finetune_no_mirror=not finetune_mirror,
            finetune_lr=finetune_lr)
        if image is not None:
            req.image.CopyFrom(_image(image, pb.KIND_PHOTO if photo else pb.KIND_NORMALIZED_FACE))
        if paste_back:
            req.output_mode = pb.OUTPUT_PASTE_BACK
        heads = head_deg or [None] * len(gaze_deg)
        if len(heads) != len(gaze_deg):
            raise ValueError("one head pose per target")
        for g, h in zip(gaze_deg, heads):
            t = req.targets.add()
            t.gaze.CopyFrom(_angles(g))
            if h is not None:
                t.head.CopyFrom(_angles(h))
        rid = self.new_id()
        self.send(FT.FRAME_REDIRECT, req, rid, subject or ZERO_KEY)
        return self._images(rid)

    def _images(self, rid):
        while True:
            ftype, got, _key, msg = self.recv()
            if got != rid:
                raise ConnectionError("frame for request %d inside request %d" % (got, rid))
            if ftype == FT.FRAME_IMAGE:
                yield msg
            elif ftype == FT.FRAME_DONE:
                return
            elif ftype == FT.FRAME_ERROR:
                raise GazesplatError(msg)
            elif ftype == FT.FRAME_BUSY:
                raise Busy(msg)
            else:
                raise ConnectionError("unexpected %s" % FT.Name(ftype))

    def cancel(self, request_id):
        """Asks the server to stop request_id; its last frame is ERROR
        ERR_CANCELLED (nothing is sent for an unknown id)."""
        self.send(FT.FRAME_CANCEL, pb.Cancel(request_id=request_id), self.new_id())


def image_array(result):
    """An ImageResult (or Image) in RAW_RGB8 as an HxWx3 numpy array."""
    import numpy as np
    img = result.image if hasattr(result, "image") else result
    if img.format != pb.FORMAT_RAW_RGB8:
        raise ValueError("decode PNG/JPEG yourself or ask for fmt='raw'")
    rows = np.frombuffer(img.data, dtype=np.uint8)
    full = np.zeros((img.height, img.stride), dtype=np.uint8).reshape(-1)
    full[:rows.size] = rows
    return full.reshape(img.height, img.stride)[:, :3 * img.width].reshape(img.height, img.width, 3)
