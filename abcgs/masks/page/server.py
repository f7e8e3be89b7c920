"""The masks page's HTTP server (:mod:`abcgs.masks.page`): the page and a small JSON API on the loopback address,
answering its own page only.

Every request carries the server's random token (in the query of the printed address, then in the cookie the page
gets with it); a request whose ``Host`` is not this server's address (DNS rebinding), with another page's ``Origin``,
or a POST not declared ``application/json`` is refused, as is a body without one plain ``Content-Length`` from 1 to
:data:`~abcgs.masks.page.requests.MAX_BODY` or one that does not arrive within
:data:`~abcgs.masks.page.requests.REQUEST_TIMEOUT_S` (:mod:`abcgs.masks.page.requests`); each refusal is a 4xx with a one-line
reason.

The API (``<i>``: a page item's index, ``<c>``: a view's index in the strip):

- ``GET /api/state``: the items, their strokes, cuts and saved state, the palette, and whether the 3-D labels are on
  (``field``: ``on`` and ``note``, why not);
- ``GET /api/image/<i>``, ``GET|POST /api/strokes/<i>``, ``POST /api/segment/<i>``, ``GET /api/labels/<i>.png``,
  ``GET /api/overlay/<i>.png``, ``POST /api/save``: the views, their strokes, the cut and Save;
- ``GET /api/strip``: with the scene's fit, every view of the strip, most doubtful first
  (:meth:`abcgs.masks.page.field_session.FieldSession.listing`); ``GET /api/strip/<c>.png``: its thumbnail, the labels in
  the page's colours over the photo, undecided white. Without a fit both are 404 with the reason.
"""

from __future__ import annotations

import json
import logging
import re
import secrets
import socket
import threading
from http import HTTPStatus
from http.cookies import SimpleCookie
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Protocol
from urllib.parse import parse_qs

import cv2
import numpy as np

from abcgs.errors import AbcgsError, InputError
from abcgs.masks.page.requests import (
    REQUEST_DEADLINE_S,
    REQUEST_TIMEOUT_S,
    Refused,
    body_flag,
    body_revision,
    body_strokes,
    content_length,
    image_index,
    read_body,
)
from abcgs.masks.strokes import Segmentation, Stroke
from abcgs.viz import colorize_labels

log = logging.getLogger(__name__)


class PageSession(Protocol):
    """What the server asks of the page's state (:class:`abcgs.masks.page.session.PaintSession` is one); ``i`` is a
    page item's index, ``camera`` a view's index in the strip."""

    field_note: str
    """Why the 3-D labels are off (the strip's 404 says it), or what they are on."""

    def state(self) -> dict: ...
    def image_png(self, i: int) -> bytes: ...
    def strokes_of(self, i: int) -> dict: ...
    def set_strokes(self, i: int, strokes: list[Stroke], revision: int | None = None) -> bool: ...
    def segment(self, i: int, fill: bool | None = None) -> Segmentation: ...
    def shown_labels(self, i: int) -> tuple[str, np.ndarray | None]: ...
    def strip_listing(self) -> dict | None: ...
    def strip_thumbnail(self, camera: int) -> np.ndarray | None: ...
    def save(self, fill: bool | None = None) -> list[Path]: ...

PAGE = Path(__file__).resolve().parent / "static" / "paint.html"
"""The drawing page (HTML + plain JavaScript in one file)."""


def overlay_rgba(labels: np.ndarray, alpha: int = 150) -> np.ndarray:
    """Label map ``(H, W)`` → ``(H, W, 4) uint8`` RGBA in the label colours, transparent where 0, with each region's
    edge opaque so that the cut reads on any image."""
    lab = np.asarray(labels)
    rgba = np.zeros((*lab.shape, 4), np.uint8)
    rgba[..., :3] = colorize_labels(lab)
    src = lab.astype(np.uint16 if lab.max(initial=0) > 255 else np.uint8)
    ring = np.ones((3, 3), np.uint8)
    edge = cv2.dilate(src, ring) != cv2.erode(src, ring)
    rgba[..., 3] = np.where(lab > 0, np.where(edge, 255, alpha), 0)
    return rgba


_ROUTE = re.compile(r"^/api/(state|image|strokes|segment|labels|overlay|save|strip)(?:/(\d+))?(?:\.png)?$")
"""``/api/<what>[/<index>][.png]``: the API's routes (module docstring)."""


def _png(arr: np.ndarray) -> bytes:
    """PNG bytes of ``arr``: ``(H, W) uint8``, ``(H, W, 3)`` RGB or ``(H, W, 4)`` RGBA."""
    if arr.ndim == 3:
        arr = cv2.cvtColor(arr, cv2.COLOR_RGBA2BGRA if arr.shape[2] == 4 else cv2.COLOR_RGB2BGR)
    ok, buf = cv2.imencode(".png", arr)
    if not ok:
        raise InputError("could not encode a PNG")
    return buf.tobytes()


class _Handler(BaseHTTPRequestHandler):
    session: PageSession  # set on the subclass :func:`make_server` builds
    token: str
    server_version = "abcgs-paint"

    def log_message(self, fmt, *args):  # requests go to the debug log, not stderr
        log.debug("%s - %s", self.address_string(), fmt % args)

    def _send(self, status: int, body: bytes, ctype: str, headers: dict[str, str] | None = None) -> None:
        self.send_response(status)
        self.send_header("Content-Type", ctype)
        for k, v in (headers or {}).items():
            self.send_header(k, v)
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "no-store")
        self.end_headers()
        self.wfile.write(body)

    def _json(self, data, status: int = 200) -> None:
        self._send(status, json.dumps(data).encode(), "application/json")

    def _hosts(self) -> set[str]:
        """The ``Host`` values of the address this server serves (``127.0.0.1:PORT``, ``localhost:PORT``)."""
        host, port = self.server.server_address[:2]
        names = {"127.0.0.1", "localhost"} if host in ("127.0.0.1", "localhost") else {"[::1]", "localhost"}
        return {f"{n}:{port}" for n in names}

    def _cookie(self) -> str:
        return f"abcgs_paint_{self.server.server_address[1]}"  # cookies are per host, not per port

    def _check_token(self, query: str) -> bool:
        """The request carries the server's token, in the query (``?token=``, the address printed at start) or in
        the cookie the page got with it; True when it came in the query (the page then sets the cookie)."""
        given = parse_qs(query).get("token", [""])[0]
        morsel = SimpleCookie(self.headers.get("Cookie", "")).get(self._cookie()) if not given else None
        value = given or (morsel.value if morsel is not None else "")
        if not secrets.compare_digest(value.encode(), self.token.encode()):
            raise Refused(HTTPStatus.FORBIDDEN, "missing or wrong token: open the address (with ?token=) that "
                                                "`python -m abcgs.masks.page` printed")
        return bool(given)

    def _check_caller(self, method: str) -> None:
        """Only the page this server serves drives it: ``Host`` is the server's own address (no DNS rebinding), an
        ``Origin`` is its own (no other web page), and a POST body is declared JSON (a cross-origin page cannot send
        that without a CORS preflight, which this server never grants)."""
        hosts = self._hosts()
        if self.headers.get("Host", "") not in hosts:
            raise Refused(HTTPStatus.FORBIDDEN, f"Host {self.headers.get('Host', '')!r} is not this server "
                                                f"({' or '.join(sorted(hosts))})")
        origin = self.headers.get("Origin")
        if origin is not None and origin not in {f"http://{h}" for h in hosts}:
            raise Refused(HTTPStatus.FORBIDDEN, f"requests from {origin[:100]!r} are refused: only this server's "
                                                "own page may use it")
        if method == "POST":
            ctype = (self.headers.get("Content-Type") or "").split(";", 1)[0].strip().lower()
            if ctype != "application/json":
                raise Refused(HTTPStatus.UNSUPPORTED_MEDIA_TYPE,
                              f"Content-Type {ctype or '(none)'!r}: the API takes application/json")

    deadline: float = REQUEST_DEADLINE_S  # set on the subclass :func:`make_server` builds
    _timer: threading.Timer | None = None

    def handle_one_request(self):
        """One request, whose headers and body must arrive within :attr:`deadline` seconds together (each read has
        its own ``timeout`` too): past it the connection is shut, so a client that drips bytes holds no thread."""
        self._timer = threading.Timer(self.deadline, self._cut_off)
        self._timer.daemon = True
        self._timer.start()
        try:
            super().handle_one_request()
        except OSError:  # the connection was shut at the deadline, or the client left
            self.close_connection = True
        finally:
            self._timer.cancel()

    def _cut_off(self) -> None:
        log.info("a request from %s did not arrive within %.0f s; connection closed", self.address_string(),
                 self.deadline)
        try:
            self.connection.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass

    def _arrived(self) -> None:
        """The request is in whole: its work is not held to the deadline."""
        if self._timer is not None:
            self._timer.cancel()

    def _body(self) -> dict:
        body = read_body(content_length(self.headers.get_all("Content-Length")), self.rfile)
        self._arrived()
        return body

    def _dispatch(self, method: str) -> None:
        path, _, query = self.path.partition("?")
        if method == "GET":
            self._arrived()
        try:
            self._check_caller(method)
            from_query = self._check_token(query)
            if method == "GET" and path in ("/", "/index.html"):
                cookie = {"Set-Cookie": f"{self._cookie()}={self.token}; HttpOnly; SameSite=Strict; Path=/"}
                return self._send(200, PAGE.read_bytes(), "text/html; charset=utf-8", cookie if from_query else None)
            m = _ROUTE.match(path)
            if not m:
                return self._json({"error": f"no such page: {path}"}, HTTPStatus.NOT_FOUND)
            what, idx = m.group(1), image_index(m.group(2))
            s = self.session
            if what in ("image", "strokes", "segment", "labels", "overlay") and idx is None:
                raise InputError(f"/api/{what}/<index> needs an image index")
            if method == "GET" and what == "state":
                return self._json(s.state())
            if method == "GET" and what == "strip":
                shown = s.strip_listing() if idx is None else s.strip_thumbnail(idx)
                if shown is None:
                    return self._json({"error": s.field_note}, HTTPStatus.NOT_FOUND)
                return self._json(shown) if idx is None else self._send(200, _png(shown), "image/png")
            if method == "GET" and what == "image":
                return self._send(200, s.image_png(idx), "image/png")
            if method == "GET" and what == "strokes":
                return self._json(s.strokes_of(idx))
            if method == "POST" and what == "strokes":
                body = self._body()
                accepted = s.set_strokes(idx, body_strokes(body), body_revision(body))
                return self._json({**s.state()["items"][idx], "accepted": accepted})
            if method == "POST" and what == "segment":
                body = self._body()
                fill = body_flag(body, "fill")
                if "strokes" in body:
                    s.set_strokes(idx, body_strokes(body), body_revision(body))
                seg = s.segment(idx, fill)
                return self._json({"counts": {str(k): v for k, v in seg.counts().items()},
                                   "seconds": round(seg.seconds, 3), "item": s.state()["items"][idx]})
            if method == "GET" and what in ("labels", "overlay"):
                name, labels = s.shown_labels(idx)
                if labels is None:
                    return self._json({"error": f"{name} is not cut yet (press Segment)"}, HTTPStatus.NOT_FOUND)
                arr = labels.astype(np.uint8) if what == "labels" else overlay_rgba(labels)
                return self._send(200, _png(arr), "image/png")
            if method == "POST" and what == "save":
                written = s.save(body_flag(self._body(), "fill"))
                return self._json({"written": [str(p) for p in written], "state": s.state()})
            return self._json({"error": f"{method} {path} is not supported"}, HTTPStatus.METHOD_NOT_ALLOWED)
        except Refused as exc:
            self.close_connection = True  # the body, if any, is left unread
            return self._json({"error": str(exc)}, exc.status)
        except AbcgsError as exc:
            return self._json({"error": str(exc)}, HTTPStatus.BAD_REQUEST)
        except Exception as exc:  # the page shows the message; the server keeps running
            log.exception("request %s %s failed", method, path)
            return self._json({"error": f"{type(exc).__name__}: {exc}"}, HTTPStatus.INTERNAL_SERVER_ERROR)

    def do_GET(self):  # noqa: N802 (http.server's names)
        self._dispatch("GET")

    def do_POST(self):  # noqa: N802
        self._dispatch("POST")


def make_server(session: PageSession, port: int = 0, host: str = "127.0.0.1", token: str | None = None,
                timeout: float = REQUEST_TIMEOUT_S, deadline: float = REQUEST_DEADLINE_S) -> ThreadingHTTPServer:
    """An HTTP server for ``session`` on ``host:port`` (0 = any free port); call ``serve_forever()`` on it. A
    connection that sends nothing for ``timeout`` seconds is answered 408 (mid-body) or closed, and one whose request
    has not arrived whole within ``deadline`` seconds is closed.

    ``server.server_port`` is the port it got. Only loopback addresses are allowed: the page can write files. Every
    request must carry ``token`` (a fresh random one by default; ``server.token``), which :func:`page_url` puts in
    the page's address, as Jupyter does: another user of the machine can reach the port, but not guess it.
    """
    if host not in ("127.0.0.1", "localhost", "::1"):
        raise InputError(f"the paint server listens on the loopback address only, not {host}")
    token = token or secrets.token_urlsafe(24)
    handler = type("PaintHandler", (_Handler,), {"session": session, "token": token, "timeout": timeout,
                                                 "deadline": deadline})
    server = ThreadingHTTPServer((host, port), handler)
    server.daemon_threads = True
    server.token = token  # type: ignore[attr-defined]
    return server


def page_url(server: ThreadingHTTPServer) -> str:
    """The page's address with the server's token (the page then keeps it in a cookie for its requests)."""
    return f"http://127.0.0.1:{server.server_port}/?token={server.token}"  # type: ignore[attr-defined]

