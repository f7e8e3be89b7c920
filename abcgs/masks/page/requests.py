"""The masks page's requests, checked before the page acts on them: one ``Content-Length`` that is a plain byte
count up to :data:`MAX_BODY`, a body that arrives whole (within the server's timeout, :data:`REQUEST_TIMEOUT_S`) and
is a JSON object of bounded depth, an image index of at most 9 digits, and the fields of the body (strokes, revision,
flags). Each refusal is a :class:`Refused` with its HTTP status and a one-line reason (:mod:`abcgs.masks.page`
answers it as JSON ``{"error": …}``)."""

from __future__ import annotations

import json
from http import HTTPStatus
from typing import BinaryIO

from abcgs.errors import AbcgsError, InputError
from abcgs.io.guarded import parse_json
from abcgs.masks.strokes import Stroke

MAX_BODY = 16 << 20
"""Largest request body read (bytes): strokes of a long session are a few MB of JSON."""
REQUEST_TIMEOUT_S = 30.0
"""Seconds a request's connection may wait for the client's next bytes (a body shorter than its ``Content-Length``
would hold its thread until the client left); then the request is answered 408 and closed."""

REQUEST_DEADLINE_S = 60.0
"""Seconds a request has to arrive whole, its headers and its body together: a client that sends one byte every few
seconds meets every read's timeout but not this; its connection is then closed."""


class Refused(AbcgsError):
    """A request the server does not serve: ``status`` (400, 403, 415) and a one-line reason."""

    def __init__(self, status: int, reason: str) -> None:
        super().__init__(reason)
        self.status = status


def read_body(content_length: str | None, rfile: BinaryIO) -> dict:
    """The JSON object of a request body of ``content_length`` bytes (the header's text) read from ``rfile``;
    :class:`Refused` (400) with a one-line reason for a length that is not a plain decimal byte count up to
    :data:`MAX_BODY`, an empty or short body, and a body that is not a JSON object."""
    text = (content_length or "").strip()
    if not (text.isascii() and text.isdigit()):  # also a negative length (rfile.read: "until the end"), or "²"
        raise Refused(HTTPStatus.BAD_REQUEST, f"Content-Length {text[:40]!r} is not a byte count")
    n = int(text) if len(text) <= len(str(MAX_BODY)) else MAX_BODY + 1  # int() refuses 4300+ digits
    if n > MAX_BODY:
        raise Refused(HTTPStatus.BAD_REQUEST, f"the body of {text if len(text) <= 20 else text[:20] + '…'} bytes is "
                                              f"larger than {MAX_BODY} bytes")
    if n == 0:
        raise Refused(HTTPStatus.BAD_REQUEST, "Content-Length 0: the request has no body; the API takes a JSON "
                                              "object ({} for none)")
    try:
        raw = rfile.read(n)
    except TimeoutError:
        raise Refused(HTTPStatus.REQUEST_TIMEOUT, f"the body of {n} bytes did not arrive in time") from None
    if len(raw) != n:
        raise Refused(HTTPStatus.BAD_REQUEST, f"the body ended after {len(raw)} of {n} bytes")
    try:
        data = parse_json(raw, "the request body")
    except InputError as exc:  # not JSON, or nested deeper than any request
        raise Refused(HTTPStatus.BAD_REQUEST, str(exc)) from None
    if not isinstance(data, dict):
        raise Refused(HTTPStatus.BAD_REQUEST, "the request body must be a JSON object")
    return data


def content_length(values: list[str] | None) -> str | None:
    """The one ``Content-Length`` of a request's header values ``values`` (``None`` when there is none);
    :class:`Refused` (400) when the request carries several that differ (which one a proxy on the way used is
    unknown: request smuggling)."""
    given = sorted({v.strip() for v in values or []})
    if len(given) > 1:
        shown = ", ".join(repr(v[:20]) for v in given[:3])
        raise Refused(HTTPStatus.BAD_REQUEST, f"{len(given)} different Content-Length headers ({shown}"
                                              f"{', …' if len(given) > 3 else ''}); a request carries one")
    return given[0] if given else None


def image_index(text: str | None) -> int | None:
    """The image index of a route (``/api/image/<index>``), ``None`` when it has none; :class:`Refused` (400) when
    it is longer than any index can be."""
    if text is None:
        return None
    if len(text) > 9 or not (text.isascii() and text.isdigit()):
        raise Refused(HTTPStatus.BAD_REQUEST, f"image index {text[:20]!r}{'…' if len(text) > 20 else ''} is not an "
                                              "index of this page's images")
    return int(text)


def body_strokes(body: dict) -> list[Stroke]:
    """``body["strokes"]``: a list of stroke objects (:meth:`Stroke.from_json`)."""
    strokes = body.get("strokes", [])
    if not isinstance(strokes, list):
        raise InputError(f"'strokes' must be a list of stroke objects, not {type(strokes).__name__}")
    return [Stroke.from_json(d) for d in strokes]


def body_revision(body: dict) -> int | None:
    """``body["revision"]``: the page's count of edits to a view's strokes (a non-negative integer), or ``None``."""
    value = body.get("revision")
    if value is not None and (not isinstance(value, int) or isinstance(value, bool) or value < 0):
        raise InputError(f"'revision' must be a non-negative integer, not {json.dumps(value)[:40]}")
    return value


def body_flag(body: dict, key: str) -> bool | None:
    value = body.get(key)
    if value is not None and not isinstance(value, bool):
        raise InputError(f"{key!r} must be true or false, not {json.dumps(value)[:40]}")
    return value
