"""The wire format both clients share (proto/PROTOCOL.md): the 32-byte frame
header, the message class of each frame type, and the request messages
built from Python values."""
from __future__ import annotations

import os
import struct
from typing import Any, Dict, Iterable, NamedTuple, Optional, Sequence, Tuple, Union

from google.protobuf.message import Message

from . import gazesplat_pb2 as pb
from .errors import Busy, GazesplatError, ProtocolError

__all__ = ["HEADER", "MAGIC", "VERSION_MIN", "VERSION_MAX", "ZERO_KEY", "DEFAULT_ADDR", "MESSAGES",
           "Frame", "pack_frame", "unpack_header", "image_message", "angles", "parse_addr",
           "fit_request", "redirect_request", "reply_error", "ImageInput", "AnglePair"]

HEADER = struct.Struct("<4sHHI16sI")
MAGIC = b"GAZE"
VERSION_MIN = VERSION_MAX = 1
ZERO_KEY = b"\0" * 16
DEFAULT_ADDR = "/run/gazesplat/gazesplatd.sock"
FT = pb.FrameType

# Frame type -> message class of its payload.
MESSAGES: Dict[int, Any] = {
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

# An image argument: PNG/JPEG bytes, or an HxWx3 uint8 array (numpy or
# anything with .shape, .dtype and .tobytes()).
ImageInput = Union[bytes, bytearray, memoryview, Any]
# (pitch, yaw) in degrees.
AnglePair = Tuple[float, float]


class Frame(NamedTuple):
    """One received frame: its type, request id, header key and message."""
    type: int
    request_id: int
    key: bytes
    message: Any


def pack_frame(ftype: int, msg: Optional[Message] = None, request_id: int = 0,
               key: bytes = ZERO_KEY, version: int = 1) -> bytes:
    """Header + payload bytes of one frame."""
    body: bytes = msg.SerializeToString() if msg is not None else b""
    key = bytes(key)
    if len(key) != 16:
        raise ValueError("a subject key is 16 bytes, not %d" % len(key))
    return HEADER.pack(MAGIC, version, ftype, len(body), key, request_id) + body


def unpack_header(head: bytes) -> Tuple[int, int, int, bytes]:
    """(type, payload length, request id, key) of a 32-byte header;
    ProtocolError for a bad magic or an unknown frame type."""
    magic, _ver, ftype, n, key, rid = HEADER.unpack(head)
    if magic != MAGIC:
        raise ProtocolError("bad magic from server: %r" % magic)
    if ftype not in MESSAGES:
        raise ProtocolError("unknown frame type %d from server" % ftype)
    return ftype, n, rid, key


def decode(ftype: int, rid: int, key: bytes, payload: bytes) -> Frame:
    try:
        msg = MESSAGES[ftype].FromString(payload)
    except Exception as e:  # google.protobuf.message.DecodeError and friends
        raise ProtocolError("undecodable %s payload from server: %s" % (FT.Name(ftype), e)) from None
    return Frame(ftype, rid, key, msg)


def reply_error(frame: Frame) -> Union[GazesplatError, Busy, None]:
    """The exception an ERROR or BUSY frame stands for; None for others."""
    if frame.type == FT.FRAME_ERROR:
        m = frame.message
        return GazesplatError(m.code, m.message, m.request_id or frame.request_id)
    if frame.type == FT.FRAME_BUSY:
        return Busy(frame.message.retry_after_ms, frame.message.queue_length, frame.request_id)
    return None


def parse_addr(addr: Optional[str]) -> Tuple[str, Any]:
    """("unix", path) or ("tcp", (host, port)) for unix:PATH, PATH or
    tcp:HOST:PORT; None: $GAZESPLAT_ADDR, else the packaged socket."""
    addr = addr or os.environ.get("GAZESPLAT_ADDR") or DEFAULT_ADDR
    if addr.startswith("tcp:"):
        host, sep, port = addr[4:].rpartition(":")
        if not sep or not port.isdigit():
            raise ValueError("address %r: want tcp:HOST:PORT" % addr)
        return "tcp", (host.strip("[]"), int(port))
    return "unix", addr[5:] if addr.startswith("unix:") else addr


def image_message(image: ImageInput, kind: Any = pb.KIND_NORMALIZED_FACE) -> Any:
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
    shape = getattr(image, "shape", None)
    if shape is None or len(shape) != 3 or shape[2] != 3 or str(getattr(image, "dtype", "")) != "uint8":
        raise ValueError("array images must be HxWx3 uint8, got %s %s"
                         % (shape, getattr(image, "dtype", type(image).__name__)))
    h, w, _ = shape
    return pb.Image(format=pb.FORMAT_RAW_RGB8, data=image.tobytes(), width=w, height=h,
                    stride=3 * w, kind=kind)


def angles(pair: Optional[Sequence[float]]) -> Any:
    """An Angles message from (pitch, yaw) degrees; None stays None."""
    if pair is None:
        return None
    if len(pair) != 2:
        raise ValueError("angles are (pitch, yaw) degrees, got %r" % (pair,))
    return pb.Angles(pitch_deg=float(pair[0]), yaw_deg=float(pair[1]))


_FORMATS = {"png": pb.FORMAT_PNG, "jpeg": pb.FORMAT_JPEG, "raw": pb.FORMAT_RAW_RGB8}


def fit_request(image: ImageInput, gaze_deg: Optional[AnglePair] = None,
                head_deg: Optional[AnglePair] = None, max_iters: int = 0, deadline_ms: int = 0,
                photo: bool = False, finetune_steps: int = 0, finetune_parts: str = "",
                keep_image: bool = False, finetune_outline_px: int = 0, finetune_mirror: bool = True,
                finetune_lr: float = 0.0, more_images: Sequence[Any] = ()) -> Any:
    """The FitRequest of Client.fit's arguments. more_images: the same
    person's other images (at most 15), each an image or a tuple (image,
    gaze_deg, head_deg) with its own labels (None: unknown)."""
    kind = pb.KIND_PHOTO if photo else pb.KIND_NORMALIZED_FACE
    req = pb.FitRequest(image=image_message(image, kind), max_iters=max_iters, deadline_ms=deadline_ms,
                        finetune_steps=finetune_steps, finetune_parts=finetune_parts,
                        keep_image=keep_image, finetune_outline_px=finetune_outline_px,
                        finetune_no_mirror=not finetune_mirror, finetune_lr=finetune_lr)
    if gaze_deg is not None:
        req.gaze.CopyFrom(angles(gaze_deg))
    if head_deg is not None:
        req.head.CopyFrom(angles(head_deg))
    if len(more_images) > 15:
        raise ValueError("at most 16 images of one person in one fit, got %d" % (1 + len(more_images)))
    for item in more_images:
        if isinstance(item, tuple) and not 1 <= len(item) <= 3:
            raise ValueError("a further image is an image or (image, gaze_deg, head_deg), got a "
                             "tuple of %d" % len(item))
        img, g, h = (item + (None, None))[:3] if isinstance(item, tuple) else (item, None, None)
        fi = req.more_images.add()
        fi.image.CopyFrom(image_message(img, kind))
        if g is not None:
            fi.gaze.CopyFrom(angles(g))
        if h is not None:
            fi.head.CopyFrom(angles(h))
    return req


def redirect_request(gaze_deg: Sequence[AnglePair], subject: Optional[bytes] = None,
                     image: Optional[ImageInput] = None,
                     head_deg: Optional[Sequence[Optional[AnglePair]]] = None, fmt: str = "png",
                     jpeg_quality: int = 0, deadline_ms: int = 0, max_iters: int = 0,
                     photo: bool = False, paste_back: bool = False, finetune_steps: int = 0,
                     finetune_parts: str = "", transfer: bool = False, finetune_outline_px: int = 0,
                     finetune_mirror: bool = True, finetune_lr: float = 0.0,
                     min_quality: float = 0.0, quality: bool = False) -> Any:
    """The RedirectRequest of Client.redirect's arguments."""
    if (subject is None) == (image is None):
        raise ValueError("give exactly one of subject and image")
    if subject is not None and len(bytes(subject)) != 16:
        raise ValueError("a subject key is 16 bytes, not %d" % len(bytes(subject)))
    if fmt not in _FORMATS:
        raise ValueError("fmt is one of %s, not %r" % (", ".join(_FORMATS), fmt))
    req = pb.RedirectRequest(
        output_format=_FORMATS[fmt], jpeg_quality=jpeg_quality, deadline_ms=deadline_ms,
        max_iters=max_iters, finetune_steps=finetune_steps, finetune_parts=finetune_parts,
        transfer=transfer, finetune_outline_px=finetune_outline_px,
        finetune_no_mirror=not finetune_mirror, finetune_lr=finetune_lr, min_quality=min_quality,
        quality=quality)
    if image is not None:
        req.image.CopyFrom(image_message(image, pb.KIND_PHOTO if photo else pb.KIND_NORMALIZED_FACE))
    if paste_back:
        req.output_mode = pb.OUTPUT_PASTE_BACK
    gazes = list(gaze_deg)
    heads: Iterable[Optional[AnglePair]] = head_deg if head_deg is not None else [None] * len(gazes)
    heads = list(heads)
    if len(heads) != len(gazes):
        raise ValueError("one head pose per target: %d gazes, %d head poses" % (len(gazes), len(heads)))
    for g, h in zip(gazes, heads):
        t = req.targets.add()
        t.gaze.CopyFrom(angles(g))
        if h is not None:
            t.head.CopyFrom(angles(h))
    return req


def live_policy_request(refit: bool, settings: Dict[str, Any]) -> Any:
    req = pb.LivePolicyRequest(refit=refit)
    for k, v in settings.items():
        if isinstance(v, bool):
            v = "yes" if v else "no"
        req.set.add(key=k, value=str(v))
    return req


def image_array(result: Any) -> Any:
    """An ImageResult (or Image) in RAW_RGB8 as an HxWx3 uint8 numpy array
    (needs numpy)."""
    import numpy as np
    img = result.image if hasattr(result, "image") else result
    if img.format != pb.FORMAT_RAW_RGB8:
        raise ValueError("decode PNG/JPEG yourself or ask for fmt='raw'")
    rows = np.frombuffer(img.data, dtype=np.uint8)
    full = np.zeros((img.height, img.stride), dtype=np.uint8).reshape(-1)
    full[:rows.size] = rows
    return full.reshape(img.height, img.stride)[:, :3 * img.width].reshape(img.height, img.width, 3)
