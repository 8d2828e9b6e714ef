"""``pipestitch review``'s local server (standard library ``http.server``).

Bound to 127.0.0.1 only. It serves the review page (editable), the files of OUT the
page loads (tiles), the source frames of a point, and the observation edits:

* ``GET /``: the page; ``GET /<path>``: a file inside OUT (403 outside it, symbolic
  links resolved first);
* ``GET /api/observations``: the rows and the file's version;
* ``POST /api/observations`` (add), ``PUT /api/observations/<row>`` (change),
  ``DELETE /api/observations/<row>``: a JSON body ``{"version": ..., "fields": {...}}``,
  validated by :func:`pipestitch.pipeline.review.edit_observations`; errors are JSON
  ``{"error": ...}`` with 400, 404 or 409;
* ``GET /api/frame?frame=N&z=MM&theta=DEG``: the LED frame with its ring and the point.

Requests whose Host is not this server's (DNS rebinding), and edits that are not JSON
or come from another origin, are refused with 403. It writes only
``OUT/observations.csv``, the exports made from it, ``OUT/standards.json`` (the
generated rows deleted in review), the observations of ``OUT/report.html`` and
``OUT/review.html``.
"""

from __future__ import annotations

import json
import math
import mimetypes
import threading
from collections.abc import Callable
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from urllib.parse import parse_qs, unquote, urlsplit

from pipestitch.errors import DatasetError
from pipestitch.pipeline.review import (
    Edit,
    EditError,
    edit_observations,
    observation_rows,
    read_observations,
    read_run_csv,
    render_review_page,
)
from pipestitch.pipeline.source_frames import FramePoses, SourceFrames

__all__ = ["ReviewServer"]

HOST = "127.0.0.1"
MAX_BODY = 64 * 1024
FRAMES_URL = "api/frame"
_METHODS = {"POST": "add", "PUT": "change", "DELETE": "delete"}


class ReviewServer:
    """The review page of ``out`` served on 127.0.0.1:``port`` (0: any free port).

    Use :meth:`serve_forever` (the command) or as a context manager running on a thread
    (the tests); :attr:`url` is the page's address.
    """

    def __init__(self, out: str | Path, *, port: int = 0, dataset: str | Path | None = None
                 ) -> None:
        self.out = Path(out).resolve()
        self.page = render_review_page(self.out)     # checks OUT before serving it
        self.lock = threading.Lock()
        self.frames = _source_frames(self.out, dataset)
        self.httpd = ThreadingHTTPServer((HOST, port), _handler(self))
        self.httpd.daemon_threads = True
        self._thread: threading.Thread | None = None

    @property
    def url(self) -> str:
        """The page's address."""
        return f"http://{HOST}:{self.httpd.server_address[1]}/"

    def page_text(self) -> str:
        """The editable page, with the current observations."""
        url = FRAMES_URL if self.frames.available else None
        return render_review_page(self.out, editable=True, frames_url=url)

    def observations(self) -> dict[str, object]:
        """The rows and version the page edits."""
        file, version = read_observations(self.out)
        return {"observations": observation_rows(file), "version": version}

    def edit(self, edit: Edit) -> dict[str, object]:
        """Apply one edit (serialised; edit_observations also refreshes OUT/review.html)."""
        with self.lock:
            rows, version = edit_observations(self.out, edit)
        return {"observations": rows, "version": version}

    def serve_forever(self) -> None:
        """Serve until interrupted."""
        self.httpd.serve_forever()

    def __enter__(self) -> ReviewServer:
        self._thread = threading.Thread(target=self.httpd.serve_forever, daemon=True)
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.httpd.shutdown()
        self.httpd.server_close()


def _source_frames(out: Path, dataset: str | Path | None) -> SourceFrames:
    meta = json.loads((out / "mosaic.json").read_text(encoding="utf-8"))
    full = meta.get("full_resolution") or meta
    if dataset is None:
        standards = out / "standards.json"
        recorded = json.loads(standards.read_text(encoding="utf-8")) if standards.is_file() else {}
        dataset = recorded.get("dataset")
    poses = FramePoses.from_rows(read_run_csv(out / "poses.csv"),
                                 read_run_csv(out / "profile.csv"))
    return SourceFrames(dataset, poses, deg_per_px=float(full["deg_per_px"]),
                        mm_per_px=float(full["mm_per_px_axial"]))


def _inside(out: Path, url_path: str) -> Path | None:
    """The file of OUT that ``url_path`` names, or None when it is outside OUT."""
    relative = unquote(url_path).lstrip("/")
    if "\x00" in relative:
        return None
    candidate = (out / relative).resolve()
    return candidate if candidate.is_relative_to(out) else None


def _handler(server: ReviewServer) -> type[BaseHTTPRequestHandler]:
    class Handler(_ReviewHandler):
        review = server
    return Handler


class _ReviewHandler(BaseHTTPRequestHandler):
    review: ReviewServer
    server_version = "pipestitch-review"

    def log_message(self, format: str, *args: object) -> None:
        """Quiet: the command prints its address; errors reach the page."""

    def _send(self, status: int, body: bytes, content_type: str) -> None:
        self.send_response(status)
        self.send_header("Content-Type", content_type)
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "no-store")
        self.send_header("X-Content-Type-Options", "nosniff")
        self.end_headers()
        if self.command != "HEAD":
            self.wfile.write(body)

    def _json(self, status: int, value: object) -> None:
        self._send(status, json.dumps(value).encode("utf-8"), "application/json")

    def _error(self, status: int, message: str) -> None:
        self._json(status, {"error": message})

    def _host_ok(self) -> bool:
        port = self.review.httpd.server_address[1]
        allowed = {f"{HOST}:{port}", f"localhost:{port}"}
        if self.headers.get("Host", "") not in allowed:
            self._error(HTTPStatus.FORBIDDEN, "forbidden: not this server's address")
            return False
        return True

    def do_GET(self) -> None:
        """The page, a file of OUT, the observations or a source frame."""
        if not self._host_ok():
            return
        url = urlsplit(self.path)
        routes: dict[str, Callable[[], None]] = {
            "/": self._page, "/review.html": self._page,
            "/api/observations": lambda: self._json(200, self.review.observations()),
            "/" + FRAMES_URL: lambda: self._frame(parse_qs(url.query)),
            "/favicon.ico": lambda: self._send(HTTPStatus.NO_CONTENT, b"", "image/x-icon")}
        route = routes.get(url.path)
        if route is not None:
            self._guarded(route)
        else:
            self._file(url.path)

    do_HEAD = do_GET

    def _guarded(self, action: Callable[[], None]) -> None:
        try:
            action()
        except EditError as exc:
            self._error(exc.status, str(exc))
        except DatasetError as exc:
            self._error(HTTPStatus.INTERNAL_SERVER_ERROR, str(exc))

    def _page(self) -> None:
        self._send(200, self.review.page_text().encode("utf-8"), "text/html; charset=utf-8")

    def _file(self, url_path: str) -> None:
        path = _inside(self.review.out, url_path)
        if path is None:
            self._error(HTTPStatus.FORBIDDEN, "forbidden: outside the run folder")
        elif not path.is_file():
            self._error(HTTPStatus.NOT_FOUND, f"not found: {unquote(url_path)}")
        else:
            kind = mimetypes.guess_type(path.name)[0] or "application/octet-stream"
            self._send(200, path.read_bytes(), kind)

    def _frame(self, query: dict[str, list[str]]) -> None:
        try:
            frame = int(query["frame"][0])
            z, theta = float(query["z"][0]), float(query["theta"][0])
        except (KeyError, IndexError, ValueError):
            raise EditError("expected frame=N&z=MM&theta=DEG") from None
        if not (math.isfinite(z) and math.isfinite(theta)):
            raise EditError("z and theta: expected finite numbers")
        if not self.review.frames.available:
            raise EditError(f"no source frames: {self.review.frames.problem}", 404)
        try:
            picture = self.review.frames.picture(frame, z, theta)
        except KeyError:
            raise EditError(f"frame {frame}: no pose in poses.csv", 404) from None
        self._send(200, picture, "image/jpeg")

    def _edit_allowed(self) -> bool:
        if not self._host_ok():
            return False
        origin = self.headers.get("Origin")
        port = self.review.httpd.server_address[1]
        if origin is not None and origin not in (f"http://{HOST}:{port}",
                                                 f"http://localhost:{port}"):
            self._error(HTTPStatus.FORBIDDEN, "forbidden: edits come from this server's page")
            return False
        if self.headers.get("Content-Type", "").split(";")[0].strip() != "application/json":
            self._error(HTTPStatus.FORBIDDEN, "forbidden: expected a JSON body")
            return False
        return True

    def _body(self) -> dict[str, object]:
        try:
            length = int(self.headers.get("Content-Length", "0"))
        except ValueError:
            raise EditError("Content-Length: expected a number") from None
        if not 0 <= length <= MAX_BODY:
            raise EditError(f"body: expected at most {MAX_BODY} bytes, got {length}", 413)
        try:
            body = json.loads(self.rfile.read(length).decode("utf-8") or "{}")
        except (UnicodeDecodeError, ValueError) as exc:
            raise EditError(f"body: not JSON ({exc})") from None
        if not isinstance(body, dict) or not isinstance(body.get("version", ""), str):
            raise EditError('body: expected {"version": "...", "fields": {...}}')
        return body

    def _edit(self) -> None:
        if not self._edit_allowed():
            return
        parts = urlsplit(self.path).path.rstrip("/").split("/")
        if parts[:3] != ["", "api", "observations"] or len(parts) > 4:
            self._error(HTTPStatus.NOT_FOUND, f"not found: {self.path}")
            return

        def apply() -> None:
            body = self._body()
            index = _row_index(parts)
            action = _METHODS[self.command]
            if (action == "add") != (index is None):
                raise EditError("add: POST /api/observations; change and delete: "
                                "PUT or DELETE /api/observations/<row>", 405)
            edit = Edit(action, index, body.get("fields"), str(body.get("version", "")))
            self._json(200, self.review.edit(edit))

        self._guarded(apply)

    do_POST = do_PUT = do_DELETE = _edit


def _row_index(parts: list[str]) -> int | None:
    if len(parts) < 4:
        return None
    if not parts[3].isdigit():
        raise EditError(f"row: expected a row number, got {parts[3]!r}", 404)
    return int(parts[3])
