"""Human play: a person plays a level or testbed in the browser with the keyboard, recorded like an agent.

This module owns the play server: one simulator (one player per server), the JSON API that drives it, and the
episode records; ``scripts/play.py`` is its command line.  The page it serves (``evaaa/play.html``) shows the
agent's 64x64 view enlarged, the four essential variables with their viable ranges, the step count, how each
episode ended and, for training levels, an optional top-down map.  Every episode that ends is appended to
``<out>/episodes.csv`` through :class:`evaaa.records.EpisodeTracker` with ``policy="human"``, the participant id and
the level: the rows the evaluation tool writes for agents, so a report can put people beside them.

JSON API (what the page uses; a bad request gets a 4xx answer ``{"error": "..."}``).  Only this machine's own pages
may call it: a request whose ``Host`` is not the server's own name (DNS rebinding) or whose ``Origin`` is another site
gets 403 and changes nothing.  The server listens on 127.0.0.1 unless told otherwise, and warns when it is.

    GET  /              the page
    GET  /api/state     the current state (see ``PlaySession._state``)
    POST /api/reset     {"level": name} (optional; default: the current level) -> the state of a new episode
    POST /api/step      {"action": 0..4} (none, forward, left, right, eat) -> the state after that decision
    GET  /map.png       the current world from above, agent marked (training levels only)
"""

from __future__ import annotations

import base64
import copy
import csv
import ipaddress
import json
import re
import secrets
import signal
import socket
import sys
import tempfile
import threading
import time
import traceback
from collections.abc import Callable, Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from datetime import datetime, timezone
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any, NoReturn
from urllib.parse import urlsplit

import cv2
import numpy as np

from .level import Level, LevelError, excerpt
from .level_files import level_names, load_level, register_level, registered_levels
from .physiology import END_TYPES, EV_NAMES
from .pictures import top_image
from .records import EPISODE_FIELDS, OPTIONAL_FIELDS, DiskError, EpisodeTracker, StepLog, append_rows, new_log_path
from .sim import ACTION_NAMES, NUM_ACTIONS, Simulator

PAGE = Path(__file__).resolve().with_name("play.html")
RECORDS_FILE = "episodes.csv"
#: columns a human record adds to an evaluation's: the server run (session) and when the episode ended (UTC):
#: episode indices restart with every run of the server, so (participant, session, episode) names an episode
SESSION_COLUMNS = ("session", "ended_at")
MAP_SIZE = 320
MAX_RATE = 30.0
#: requests carry a level name or an action; anything larger is not from the page
MAX_BODY_BYTES = 4096
#: a larger body is still read (and dropped) up to this size, so that its sender gets the refusal
DRAIN_BYTES = 1 << 20
PARTICIPANT = re.compile(r"[\w.@-]+")
#: seconds a connection may stay silent (before its request, or between the parts of one) before it is closed:
#: a browser sends a request at once, and a stalled client must not hold a thread for ever
IDLE_TIMEOUT = 10.0
#: seconds from a request's first line to the end of its body: a client trickling its body a byte at a time (never
#: silent for IDLE_TIMEOUT) is answered 408 when they are up, and the body is read before a request slot is taken
REQUEST_DEADLINE = 5.0
#: requests answered at once (the others wait for the one simulator); beyond them the server answers 503 at once
#: rather than letting requests pile up
MAX_REQUESTS = 16


# ------------------------------------------------------------------------------------------------- settings
def _setting(
    default: Any,
    meaning: str,
    *,
    choices: Callable[[], Any] | None = None,
    check: tuple[Callable[[Any], bool], str] | None = None,
) -> Any:
    """A field of :class:`PlaySettings` with what it means and what is allowed, in the field metadata that
    ``scripts/play.py``'s command line (``evaaa_baselines.cli``) reads for ``--help`` and its messages."""
    metadata = {"meaning": meaning, "choices": choices, "check": check}
    if isinstance(default, dict):
        return field(default_factory=lambda: copy.deepcopy(default), metadata=metadata)
    return field(default=default, metadata=metadata)


@dataclass(frozen=True)
class PlaySettings:
    """What a play server does: the keys of ``scripts/play.py``'s command line."""

    level: str = _setting(
        "1-1",
        "level or testbed to play (the page can switch to another): a packaged one, the name of a file in level_dir, "
        "or the path of a .yaml level file of your own",
        choices=lambda: (*level_names(), *registered_levels()),
    )
    level_dir: Path | None = _setting(
        None,
        "a folder of your own level files (*.yaml): each is offered by its name "
        "(the file's stem) beside the packaged levels; the page can ask for no "
        "other file",
    )
    participant: str = _setting(
        "anonymous",
        "participant id written to every record (letters, digits, . _ @ -)",
        check=(lambda v: bool(PARTICIPANT.fullmatch(v)), "letters, digits and . _ @ - only"),
    )
    host: str = _setting("127.0.0.1", "address to listen on (127.0.0.1: this machine only)")
    port: int = _setting(
        8000, "port to listen on (0 picks a free one)", check=(lambda v: 0 <= v <= 65535, "a port in [0, 65535]")
    )
    seed: int = _setting(
        0,
        "seed of the worlds' layouts (the same for every participant: they meet the same worlds)",
        check=(lambda v: 0 <= v < 2**63, "an integer in [0, 2**63)"),
    )
    rate: float = _setting(
        0.0,
        f"decisions per second; 0 steps once per key press (at most {MAX_RATE:g})",
        check=(lambda v: 0 <= v <= MAX_RATE, f"a number in [0, {MAX_RATE:g}]"),
    )
    out: Path = _setting(Path("outputs/human"), "directory of the records, <out>/episodes.csv")
    step_log: bool = _setting(
        False, "also log every decision to <out>/steps-<UTC time>.csv (one row per decision: evaaa.records.STEP_FIELDS)"
    )
    #: level fields by dotted path (``episode.max_steps: 5``), applied to every level played
    overrides: dict[str, Any] = _setting(
        {},
        "any level field by its dotted path, as in make_env, e.g. "
        "overrides.episode.max_steps=200 (null removes an entry)",
    )


# ------------------------------------------------------------------------------------------------- the game
class RequestError(Exception):
    """A request the server refuses: answered with ``status`` and ``{"error": message}``."""

    def __init__(self, status: int, message: str):
        super().__init__(message)
        self.status, self.message = status, message


def png_data_url(rgb: np.ndarray) -> str:
    ok, png = cv2.imencode(".png", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    assert ok, "PNG encoding of a uint8 image cannot fail"
    return "data:image/png;base64," + base64.b64encode(png.tobytes()).decode("ascii")


class StartupError(Exception):
    """The server cannot start as asked (for example, its records cannot be written)."""


def new_session_id() -> str:
    """An id for one run of the server: its start time (UTC) and a random suffix, e.g. 20260101T120000Z-3fa9c1."""
    return f"{datetime.now(timezone.utc):%Y%m%dT%H%M%SZ}-{secrets.token_hex(3)}"


def register_level_dir(folder: Path) -> tuple[str, ...]:
    """Make every level file in ``folder`` (``*.yaml``, ``*.yml``) playable by its name; each is loaded, so checked,
    now.  Raises :class:`LevelError` naming the file that cannot be used."""
    try:
        # every .yaml entry, not only regular files: a FIFO or a folder named so is refused naming it, not skipped
        files = sorted(p for p in Path(folder).iterdir() if p.suffix in (".yaml", ".yml"))
    except OSError as exc:
        raise LevelError(f"level_dir {folder} cannot be read: {exc.strerror or exc}") from None
    return tuple(register_level(path) for path in files)


def playable_levels() -> tuple[str, ...]:
    """The names a request may ask for: the packaged levels, then those of ``level_dir``."""
    return (*level_names(), *registered_levels())


def check_records(path: Path) -> None:
    """Fail now, not at the end of the first episode, where ``path`` cannot take human records."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        # a real write, not os.access: root passes every permission check yet cannot write a read-only mount
        with tempfile.NamedTemporaryFile(dir=path.parent, prefix=".write-test-"):
            pass
        if path.exists():
            with path.open("a"):  # opened for appending, nothing written
                pass
            with path.open(newline="") as f:
                header = next(csv.reader(f), [])
            # an evaluation's columns and the session's; optional columns added later are widened in by append_rows
            known = {*EPISODE_FIELDS, *OPTIONAL_FIELDS, *SESSION_COLUMNS}
            if header and (set(header) - known or not {*EPISODE_FIELDS, *SESSION_COLUMNS} <= set(header)):
                raise StartupError(
                    f"{path} holds other columns ({', '.join(header)}): it was not written by this "
                    "version of play.py; choose another out= directory"
                )
    except OSError as exc:
        raise StartupError(f"cannot write records in {path.parent}: {exc.strerror or exc}") from None


class PlaySession:
    """The server's one simulator, the episode being played, and its records.

    Every simulator call runs on one worker thread.  That serialises the requests of the threaded server (the
    lock a single simulator needs) and keeps MuJoCo's EGL context in the thread that made it current: an EGL
    context belongs to one thread at a time, so a lock around calls from changing threads would not do.
    """

    def __init__(self, options: PlaySettings):
        self.options = options
        self.records = options.out / RECORDS_FILE
        check_records(self.records)
        self.session_id = new_session_id()
        self._worker = ThreadPoolExecutor(max_workers=1, thread_name_prefix="evaaa-sim")
        self.sim: Simulator | None = None
        self.tracker: EpisodeTracker | None = None
        self.done = False
        self.step_log = (
            StepLog(new_log_path(options.out), policy="human", participant=options.participant)
            if options.step_log
            else None
        )
        try:
            self._run(self._reset, options.level)
        except RequestError as exc:  # the level asked for on the command line cannot be played
            self._worker.shutdown()
            raise StartupError(" ".join(exc.message.split())) from None

    def _run(self, fn: Callable[..., Any], *args: Any) -> Any:
        return self._worker.submit(fn, *args).result()

    def state(self) -> dict[str, Any]:
        return self._run(self._state)

    def reset(self, level: str | None = None) -> dict[str, Any]:
        return self._run(self._reset, level)

    def step(self, action: int) -> dict[str, Any]:
        return self._run(self._step, action)

    def map_png(self) -> bytes:
        return self._run(self._map_png)

    def close(self) -> None:
        if self.sim is not None:
            self._run(self.sim.close)
        if self.step_log is not None:
            self._run(self.step_log.close)
        self._worker.shutdown()

    # -------------------------------------------------------------------------------- on the worker thread
    def _open_level(self, name: str) -> np.ndarray:
        """Replace the simulator by one of level ``name``, reset; returns its first frame.  The new simulator is built
        and reset before the old one is closed: a level that validates but cannot be played (MuJoCo refuses a body,
        items find no free spot) is answered 400 and the old level plays on."""
        if name not in playable_levels():  # a name, never a path: a request must not make the server read a file
            raise RequestError(400, f"unknown level {excerpt(name)}; available: {', '.join(playable_levels())}")
        try:
            level = load_level(name, self.options.overrides)
        except LevelError as exc:
            raise RequestError(400, str(exc)) from None
        sim = None
        try:
            # the player sees pixels; the EVs are read from the simulator, so no other sensor is computed
            sim = Simulator(level, 1, modalities=["pixels"], seed=self.options.seed)
            frame = sim.reset()["pixels"][0]
        except LevelError as exc:
            if sim is not None:
                sim.close()
            still = f"; level {self.level.name} plays on" if self.sim is not None else ""
            raise RequestError(400, f"level {name} cannot be played: {' '.join(str(exc).split())}{still}") from None
        except BaseException:  # a bug: answered 500, and the old simulator still serves
            if sim is not None:
                sim.close()
            raise
        if self.sim is not None:
            self.sim.close()
        self.level: Level = level
        self.sim = sim
        return frame

    def _reset(self, level: str | None) -> dict[str, Any]:
        unfinished = 0 if self.sim is None or self.done else int(self.sim.steps[0])
        frame = None
        if level is not None and (self.sim is None or level != self.level.name):
            frame = self._open_level(level)  # a level that cannot be played raises here and leaves the episode be
        if unfinished:
            print(
                f"episode {self.episode} abandoned after {unfinished} steps (not recorded)", file=sys.stderr, flush=True
            )
        # a fresh tracker per episode drops the sums of an abandoned one; the episode index runs on, as it does
        # within one run of the evaluation tool
        self.episode = self.tracker.episodes if self.tracker is not None else 0
        self.tracker = EpisodeTracker(
            1, level=self.level.name, policy="human", participant=self.options.participant, seed=self.options.seed
        )
        self.tracker.episodes = self.episode
        self.frame = self.sim.reset()["pixels"][0] if frame is None else frame
        if self.step_log is not None:
            self.step_log.start(self.level.name, self.sim.last_info, seed=self.options.seed)
        self.done, self.end_type, self.returned, self.record_error = False, None, 0.0, None
        return self._state()

    def _step(self, action: int) -> dict[str, Any]:
        if self.done:
            raise RequestError(409, f"the episode ended ({self.end_type}); POST /api/reset starts a new one")
        obs, reward, terminated, truncated, info = self.sim.step(np.array([action]))
        self.frame = obs["pixels"][0]
        self.returned += float(reward[0])
        self.done = bool(terminated[0] or truncated[0])
        rows = self.tracker.update(reward, info, terminated | truncated, actions=np.array([action]))
        if self.step_log is not None:
            try:
                self.step_log.update(np.array([action]), reward, info, terminated | truncated)
            except DiskError as exc:  # the game goes on; the page shows that the log stopped
                self.record_error = f"the step log stopped: {exc}"
                print(self.record_error, file=sys.stderr, flush=True)
                self.step_log = None
        ended_at = datetime.now(timezone.utc).isoformat(timespec="seconds")
        rows = [{**row, "session": self.session_id, "ended_at": ended_at} for row in rows]
        if self.done:
            self.end_type = END_TYPES[int(info["end_type"][0, 0])]
            try:
                append_rows(self.records, rows)
            except (OSError, ValueError) as exc:  # the step stands; the page shows that its record is missing
                self.record_error = f"could not record the episode in {self.records}: {exc}"
                print(self.record_error, file=sys.stderr, flush=True)
        return self._state()

    def _state(self) -> dict[str, Any]:
        sim, level = self.sim, self.level
        return {
            "level": level.name,
            "kind": level.kind,
            "description": level.description,
            "levels": list(playable_levels()),
            "participant": self.options.participant,
            "session": self.session_id,
            "episode": self.episode,
            "step": int(sim.steps[0]),
            "max_steps": level.episode.max_steps,
            "done": self.done,
            "end_type": self.end_type,
            "return": self.returned,
            "ev_names": list(EV_NAMES),
            "ev": [float(v) for v in sim.ev[0]],
            "low": [float(v) for v in sim.params.low],
            "high": [float(v) for v in sim.params.high],
            "setpoint": [float(v) for v in sim.params.setpoint],
            "frame": png_data_url(self.frame),
            "map_available": level.kind == "training",
            "rate": self.options.rate,
            "records": str(self.records),
            "record_error": self.record_error,
        }

    def _map_png(self) -> bytes:
        if self.level.kind != "training":
            raise RequestError(404, f"{self.level.name} is a testbed: its layout is not shown")
        ok, png = cv2.imencode(".png", cv2.cvtColor(top_image(self.sim, 0, MAP_SIZE), cv2.COLOR_RGB2BGR))
        assert ok, "PNG encoding of a uint8 image cannot fail"
        return png.tobytes()


# ------------------------------------------------------------------------------------------------- HTTP
def read_body(handler: BaseHTTPRequestHandler, deadline: float) -> bytes:
    """The request's body, at most :data:`MAX_BODY_BYTES`, read whole by ``deadline`` (``time.monotonic()``) or
    refused 408; a larger one is refused 413 (read and dropped first up to :data:`DRAIN_BYTES`: a socket closed on
    unread data may reset before the answer)."""
    try:
        length = int(handler.headers.get("Content-Length") or 0)
    except ValueError:
        raise RequestError(400, "Content-Length is not a number") from None
    if length > MAX_BODY_BYTES:
        if length <= DRAIN_BYTES:
            _read_until(handler, length, deadline)
        raise RequestError(413, f"request body over {MAX_BODY_BYTES} bytes")
    return _read_until(handler, length, deadline) if length > 0 else b""


def _read_until(handler: BaseHTTPRequestHandler, length: int, deadline: float) -> bytes:
    """``length`` bytes of the request, each read given only the time left before ``deadline``."""
    parts, got = [], 0
    try:
        while got < length:
            left = deadline - time.monotonic()
            if left <= 0:
                raise TimeoutError
            handler.connection.settimeout(left)
            part = handler.rfile.read1(length - got)
            if not part:  # the client closed its side before sending what it announced
                raise RequestError(400, f"request body ended after {got} of {length} bytes")
            parts.append(part)
            got += len(part)
    except TimeoutError:
        handler.close_connection = True
        raise RequestError(408, f"request not received within {REQUEST_DEADLINE:g} s") from None
    finally:
        handler.connection.settimeout(handler.timeout)  # back to the idle timeout between requests
    return b"".join(parts)


def read_json(handler: BaseHTTPRequestHandler) -> dict[str, Any]:
    """The request's JSON object body ({} when there is none): the body :meth:`PlayHandler._dispatch` read before
    the request took a slot, or (a handler of another server) read now."""
    raw = getattr(handler, "body", None)
    if raw is None:
        raw = read_body(handler, time.monotonic() + REQUEST_DEADLINE)
    if not raw.strip():
        return {}
    try:
        body = json.loads(raw)
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise RequestError(400, f"malformed JSON: {exc}") from None
    except RecursionError:  # a few kilobytes of brackets nest deeper than the parser's recursion
        raise RequestError(400, "malformed JSON: nested too deeply") from None
    if not isinstance(body, dict):
        raise RequestError(400, f"expected a JSON object, got {type(body).__name__}")
    return body


def only_keys(body: Mapping[str, Any], allowed: tuple[str, ...]) -> None:
    unknown = sorted(set(body) - set(allowed))
    if unknown:
        raise RequestError(400, f"unknown field(s) {', '.join(unknown)}; allowed: {', '.join(allowed)}")


def api_state(handler: PlayHandler) -> None:
    handler.send_json(200, handler.server.session.state())


def api_reset(handler: PlayHandler) -> None:
    body = read_json(handler)
    only_keys(body, ("level",))
    level = body.get("level")
    if level is not None and level not in playable_levels():  # refused before the simulator's queue
        raise RequestError(400, f"unknown level {excerpt(level)}; available: {', '.join(playable_levels())}")
    handler.send_json(200, handler.server.session.reset(level))


def api_step(handler: PlayHandler) -> None:
    body = read_json(handler)
    only_keys(body, ("action",))
    action = body.get("action")
    # bool is an int in Python but not an action; floats such as 1.0 are refused like any other non-integer
    if type(action) is not int or not 0 <= action < NUM_ACTIONS:
        names = ", ".join(f"{i} {name}" for i, name in enumerate(ACTION_NAMES))
        raise RequestError(400, f"action must be an integer in 0..{NUM_ACTIONS - 1} ({names}), got {action!r}")
    handler.send_json(200, handler.server.session.step(action))


def page(handler: PlayHandler) -> None:
    handler.send_body(200, "text/html; charset=utf-8", handler.server.page)


def map_png(handler: PlayHandler) -> None:
    handler.send_body(200, "image/png", handler.server.session.map_png())


#: path -> method -> what answers it
ROUTES: dict[str, dict[str, Callable[[PlayHandler], None]]] = {
    "/": {"GET": page},
    "/api/state": {"GET": api_state},
    "/api/reset": {"POST": api_reset},
    "/api/step": {"POST": api_step},
    "/map.png": {"GET": map_png},
}


def is_loopback(host: str) -> bool:
    """Whether listening on ``host`` keeps the server to this machine."""
    if host.lower() == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


def _is_ip(name: str) -> bool:
    try:
        ipaddress.ip_address(name)
        return True
    except ValueError:
        return False


class PlayHandler(BaseHTTPRequestHandler):
    server: PlayServer

    def do_GET(self) -> None:
        self._dispatch()

    def do_HEAD(self) -> None:  # GET's status and headers without the body
        self._dispatch()

    def do_OPTIONS(self) -> None:
        self._dispatch()

    def do_POST(self) -> None:
        self._dispatch()

    def do_PUT(self) -> None:
        self._dispatch()

    def do_DELETE(self) -> None:
        self._dispatch()

    def setup(self) -> None:
        self.timeout = self.server.idle_timeout  # http.server closes a connection silent for this long
        super().setup()

    def parse_request(self) -> bool:
        # called once the request line is in: the request's deadline counts from here (headers and body)
        self._started, self.body = time.monotonic(), None
        return super().parse_request()

    def _dispatch(self) -> None:
        path = urlsplit(self.path).path
        self._allow = ""
        busy = False
        try:
            self._check_caller()  # before anything is read or changed
            methods = ROUTES.get(path)
            if methods is None:
                raise RequestError(
                    404,
                    f"unknown path {path}; the API is: "
                    + ", ".join(f"{m} {p}" for p, ms in ROUTES.items() for m in ms),
                )
            allowed = [*methods, *(["HEAD"] if "GET" in methods else []), "OPTIONS"]
            self._allow = ", ".join(allowed)
            if self.command == "OPTIONS":  # no CORS headers: a browser keeps other sites' pages out
                self.send_body(204, "", b"")
                return
            answer = methods.get("GET" if self.command == "HEAD" else self.command)
            if answer is None:
                raise RequestError(405, f"{path} answers {', '.join(methods)}, not {self.command}")
            # the whole body before a slot: a slow client holds its own thread, never one of the slots
            self.body = read_body(self, self._started + REQUEST_DEADLINE)
            busy = not self.server.slots.acquire(blocking=False)
            if busy:
                raise RequestError(503, f"busy: {self.server.max_requests} requests are being answered; try again")
            try:
                answer(self)
            finally:
                self.server.slots.release()
        except RequestError as exc:
            self.close_connection = True  # a refused request's body may be left unread
            self.send_json(exc.status, {"error": exc.message}, retry=exc.status == 503)
        except ConnectionError:  # the page went away (a reload, a closed tab): nobody to answer
            self.close_connection = True
        except Exception as exc:  # noqa: BLE001 - a bug answers 500 and the server goes on serving
            traceback.print_exc()
            self.send_json(500, {"error": f"internal error: {type(exc).__name__}: {exc}"})

    def _check_caller(self) -> None:
        """Refuse (403) requests that a page from another site makes through the player's browser.

        ``Host`` must name this server (a web page cannot choose it, except by DNS rebinding: pointing a name of its
        own at 127.0.0.1, which leaves its name in ``Host``); ``Origin`` and ``Sec-Fetch-Site``, which browsers set
        on cross-site requests, must say the request comes from this server's own page."""
        hosts = self.headers.get_all("Host") or []
        if len(hosts) > 1:  # which one counts differs between servers and proxies: none does
            raise RequestError(400, f"refused: {len(hosts)} Host headers; a request names its server once")
        host = hosts[0] if hosts else None
        if host is None or not self.server.is_own_host(host):
            raise RequestError(
                403,
                f"refused: Host {host!r} is not this server "
                f"({', '.join(self.server.own_hosts())}); open the address play.py printed",
            )
        origin = self.headers.get("Origin")
        if origin is not None:
            parts = urlsplit(origin)
            if parts.scheme != "http" or not self.server.is_own_host(parts.netloc):
                raise RequestError(
                    403,
                    f"refused: requests from {origin} are not allowed; only this server's own page may call the API",
                )
        site = self.headers.get("Sec-Fetch-Site")
        # a link elsewhere (a study's instructions) may open the page itself, in a tab of its own, not in a frame
        opens_page = (
            self.command in ("GET", "HEAD")
            and urlsplit(self.path).path == "/"
            and self.headers.get("Sec-Fetch-Mode") == "navigate"
            and self.headers.get("Sec-Fetch-Dest") == "document"
        )
        if site is not None and site not in ("same-origin", "none") and not opens_page:
            raise RequestError(403, f"refused: a {site} request; only this server's own page may call the API")

    def send_json(self, status: int, payload: Mapping[str, Any], retry: bool = False) -> None:
        self.send_body(status, "application/json", json.dumps(payload).encode(), retry)

    def send_body(self, status: int, content_type: str, body: bytes, retry: bool = False) -> None:
        try:
            self.send_response(status)
            if retry:
                self.send_header("Retry-After", "1")
            if content_type:
                self.send_header("Content-Type", content_type)
            if getattr(self, "_allow", "") and status in (204, 405):
                self.send_header("Allow", self._allow)
            self.send_header("Content-Length", str(len(body)))
            self.send_header("Cache-Control", "no-store")
            # no other site may show the page in a frame and steer the player's keys
            self.send_header("X-Frame-Options", "DENY")
            self.send_header("Content-Security-Policy", "frame-ancestors 'none'")
            self.end_headers()
            if self.command != "HEAD":
                self.wfile.write(body)
        except ConnectionError:  # the page went away before its answer: nothing to report
            self.close_connection = True

    def log_request(self, code: int | str = "-", size: int | str = "-") -> None:
        # a player makes several requests a second; log only the refused ones
        if isinstance(code, int) and code >= 400:
            super().log_request(code, size)


class PlayServer(ThreadingHTTPServer):
    """The HTTP server holding the session and the page.

    Each connection has a thread; one silent for ``idle_timeout`` seconds is closed, and beyond ``max_requests``
    requests being answered at once the next are answered 503 (the page retries) instead of queueing."""

    #: connections waiting to be accepted (socketserver's default of 5 overflowed under 40 clients)
    request_queue_size = 128

    def __init__(
        self,
        host: str,
        port: int,
        page_html: bytes,
        *,
        idle_timeout: float | None = None,
        max_requests: int | None = None,
    ):
        if ":" in host:
            self.address_family = socket.AF_INET6
        self.idle_timeout = IDLE_TIMEOUT if idle_timeout is None else idle_timeout
        self.max_requests = MAX_REQUESTS if max_requests is None else max_requests
        self.slots = threading.BoundedSemaphore(self.max_requests)
        super().__init__((host, port), PlayHandler)
        self.page = page_html
        self.session: PlaySession | None = None
        self.host = host.strip("[]").lower()

    def own_hosts(self) -> list[str]:
        """The names (with the port) under which pages may reach this server."""
        port = self.server_address[1]
        names = ["127.0.0.1", "localhost", "[::1]"]
        if self.host not in ("127.0.0.1", "localhost", "::1"):
            names.append(f"[{self.host}]" if ":" in self.host else self.host)
        return [f"{name}:{port}" for name in names]

    def is_own_host(self, host: str) -> bool:
        """Whether a ``Host`` header (or an origin's host:port) names this server."""
        try:
            parts = urlsplit(f"//{host}")
            name, port = (parts.hostname or "").lower(), parts.port or 80
        except ValueError:  # a malformed port
            return False
        if port != self.server_address[1]:
            return False
        if name in ("localhost", self.host) or (_is_ip(name) and ipaddress.ip_address(name).is_loopback):
            return True
        # listening on every interface, a page may use any of this machine's addresses, but never a domain name
        # (which could be a rebinding one)
        return self.host in ("0.0.0.0", "::", "") and _is_ip(name)

    def handle_error(self, request: Any, client_address: Any) -> None:
        if isinstance(sys.exc_info()[1], ConnectionError):
            return  # a browser dropped its connection (reload, closed tab): routine, not an error
        super().handle_error(request, client_address)


# ------------------------------------------------------------------------------------------------- serving
def _stop(signum: int, frame: Any) -> NoReturn:
    raise KeyboardInterrupt  # `kill` stops the server as cleanly as Ctrl-C


def serve(options: PlaySettings, prog: str = "play.py") -> int:
    """Serve the page and its API until Ctrl-C or SIGTERM; returns the exit status (1: it could not start, with a
    line on stderr that begins with ``prog``)."""
    try:
        server = PlayServer(options.host, options.port, PAGE.read_bytes())
    except OSError as exc:
        print(f"{prog}: error: cannot listen on {options.host}:{options.port}: {exc}", file=sys.stderr)
        return 1
    signal.signal(signal.SIGTERM, _stop)
    if not is_loopback(options.host):
        print(
            f"{prog}: WARNING: listening on {options.host}, not on this machine only: anyone who can reach it "
            "can play, and their episodes are recorded as this participant's. Prefer the default host and an "
            "ssh tunnel (docs/play.md).",
            file=sys.stderr,
            flush=True,
        )
    try:
        if options.level_dir is not None:
            try:
                register_level_dir(options.level_dir)
            except LevelError as exc:
                raise StartupError(" ".join(str(exc).split())) from None
        server.session = PlaySession(options)
        host, port = server.server_address[:2]
        url_host = f"[{host}]" if ":" in host else host
        overrides = " ".join(f"{k}={v}" for k, v in options.overrides.items())
        print(
            f"evaaa play: level {options.level}, participant {options.participant}, seed {options.seed}"
            + (f", {options.rate:g} decisions/s" if options.rate else ", one decision per key press")
            + (f", overrides {overrides}" if overrides else "")
        )
        print(f"  open http://{url_host}:{port}/ in a browser (one player at a time)")
        print(f"  finished episodes are appended to {server.session.records}")
        print("  Ctrl-C stops the server", flush=True)
        server.serve_forever()
    except StartupError as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        pass
    finally:
        server.server_close()
        if server.session is not None:
            server.session.close()
    return 0
