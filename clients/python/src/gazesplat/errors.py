"""The exceptions of the gazesplat clients.

They carry plain fields only (ints and strings, never protobuf messages), so
that they pickle: a PyTorch DataLoader worker sends its exception to the main
process by pickling it, and the main process re-raises the same exception.
PyTorch's DataLoader instead re-creates the exception from one string (its
type called with the worker's formatted traceback); the constructors accept
that too and recover the code and fields from the text.
"""
from __future__ import annotations

import re
from typing import Any, Optional, Tuple

__all__ = ["GazesplatError", "Busy", "ProtocolError", "RETRYABLE_CODES", "retryable"]

# Error codes a request may be retried after, unchanged, on a new
# connection: the daemon (or the one a proxy chose) could not take it now
# but another, or the same one shortly, can (docs/scale-out.md, "What a
# client does"). ERR_UNKNOWN_SUBJECT is not among them: the request needs a
# FIT first (gazesplat.routing refits and retries).
RETRYABLE_CODES = frozenset((
    7,   # ERR_TIMEOUT: an idle connection was closed
    8,   # ERR_TOO_MANY_CONNECTIONS
    22,  # ERR_LOADING
    28,  # ERR_SHUTTING_DOWN: draining; a proxy sends the next one elsewhere
))


class GazesplatError(Exception):
    """An ERROR frame from the server: `code` (an ErrorCode number), its
    `name` ("ERR_DEADLINE", ...), the server's `message` and the
    `request_id` it answered (0 for a connection error)."""

    code: int
    name: str
    message: str
    request_id: int

    def __init__(self, code: Any, message: str = "", request_id: int = 0,
                 name: Optional[str] = None) -> None:
        if hasattr(code, "code") and hasattr(code, "message"):
            # An Error message (the constructor of older clients).
            message, request_id, code = code.message, code.request_id, code.code
        elif isinstance(code, str) and not message:
            # One text (PyTorch's DataLoader re-raising a worker's error):
            # the code from its last "GazesplatError: ERR_...".
            message, code = code, 0
            m = re.match(r"GazesplatError: (ERR_[A-Z_]+|\d+)(?::|$)",
                         message[message.rfind("GazesplatError: "):])
            if m:
                name = m.group(1)
                code = int(name) if name.isdigit() else error_code(name)
        self.code = int(code)
        self.message = str(message)
        self.request_id = int(request_id)
        self.name = name if name is not None else error_name(self.code)
        super().__init__(self.code, self.message, self.request_id, self.name)

    @property
    def retryable(self) -> bool:
        """The same request may succeed on a new connection (RETRYABLE_CODES)."""
        return self.code in RETRYABLE_CODES

    def __reduce__(self) -> Tuple[Any, ...]:
        return (type(self), (self.code, self.message, self.request_id, self.name))

    @property
    def refusal(self) -> str:
        """For ERR_FACE_REFUSED, why the server's face gate refused the
        input: "no_face", "flat", "noise", "at_border", "small_eyes",
        "eyes_closed" or "head_pose" (docs/face.md, "The gate"); "" for any
        other error. The server's message names it first, so the reason
        survives pickling with the message."""
        m = re.match(r"face refused \(([a-z_]+)\)", self.message)
        return m.group(1) if m and self.name == "ERR_FACE_REFUSED" else ""

    def __str__(self) -> str:
        return "%s: %s" % (self.name, self.message) if self.message else self.name

    def __repr__(self) -> str:
        return "%s(code=%d, name=%r, message=%r, request_id=%d)" % (
            type(self).__name__, self.code, self.name, self.message, self.request_id)


class Busy(Exception):
    """A BUSY frame: the server's queue was full and the request was not
    taken. Retry after `retry_after_ms`."""

    retry_after_ms: int
    queue_length: int
    request_id: int
    message: str
    name = "BUSY"
    retryable = True  # after retry_after_ms

    def __init__(self, retry_after_ms: Any, queue_length: int = 0, request_id: int = 0) -> None:
        text = None
        if hasattr(retry_after_ms, "retry_after_ms"):
            # A Busy message (the constructor of older clients).
            queue_length, retry_after_ms = retry_after_ms.queue_length, retry_after_ms.retry_after_ms
        elif isinstance(retry_after_ms, str):
            # One text (PyTorch's DataLoader re-raising a worker's error).
            text = retry_after_ms
            m = re.search(r"busy \((\d+) queued\), retry after (\d+) ms", text[text.rfind("Busy: "):])
            queue_length, retry_after_ms = (int(m.group(1)), int(m.group(2))) if m else (0, 0)
        self.retry_after_ms = int(retry_after_ms)
        self.queue_length = int(queue_length)
        self.request_id = int(request_id)
        self.message = text or "server busy (%d queued), retry after %d ms" % (
            self.queue_length, self.retry_after_ms)
        super().__init__(self.retry_after_ms, self.queue_length, self.request_id)

    def __reduce__(self) -> Tuple[Any, ...]:
        return (type(self), (self.retry_after_ms, self.queue_length, self.request_id))

    def __str__(self) -> str:
        return self.message

    def __repr__(self) -> str:
        return "Busy(retry_after_ms=%d, queue_length=%d, request_id=%d)" % (
            self.retry_after_ms, self.queue_length, self.request_id)


class ProtocolError(ConnectionError):
    """The server's bytes broke the protocol (bad magic, an unknown frame
    type, a reply for another request): the connection is unusable."""


def retryable(exc: BaseException) -> bool:
    """Whether a failed request may be sent again, unchanged, on a new
    connection: a lost connection (the daemon died, a proxy closed it, a
    reset, a refused connect; not a ProtocolError, which is a bug), BUSY,
    or an error in RETRYABLE_CODES. A socket timeout is not: the server may
    still be working on the request."""
    if isinstance(exc, (GazesplatError, Busy)):
        return bool(exc.retryable)
    if isinstance(exc, (ProtocolError, TimeoutError)):
        return False
    return isinstance(exc, (ConnectionError, OSError))


def error_code(name: str) -> int:
    """ErrorCode number of an ERR_... name; 0 (ERR_NONE) when unknown."""
    from . import gazesplat_pb2 as pb
    try:
        return int(pb.ErrorCode.Value(name))
    except ValueError:
        return 0


def error_name(code: int) -> str:
    """ERR_... name of an ErrorCode number; the number itself when this
    client does not know it."""
    from . import gazesplat_pb2 as pb
    try:
        return str(pb.ErrorCode.Name(code))
    except ValueError:
        return str(code)
