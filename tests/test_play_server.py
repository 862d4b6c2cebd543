"""The play server's defences and records (evaaa/play.py, run by scripts/play.py): only this machine's own page may
drive it, odd requests get 4xx answers, and every human record says which run of the server it came from and when it
ended."""

from __future__ import annotations

import http.client
import io
import json
import re
import socket
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from urllib.parse import urlsplit

from helpers import play_server

from evaaa import play
from evaaa.play import PlayHandler, PlayServer, PlaySettings, is_loopback, serve
from evaaa.records import read_rows


@contextmanager
def server(workdir: Path, *args: str) -> Iterator[tuple[str, int]]:
    """``scripts/play.py level=1-1 participant=p01 port=0 *args`` running in ``workdir``; yields (host, port)."""
    with play_server(workdir, *args, participant="p01") as url:
        address = urlsplit(url)
        yield address.hostname, address.port


def call(
    address: tuple[str, int],
    method: str,
    path: str,
    body: bytes | None = None,
    headers: dict[str, str] | None = None,
    timeout: float = 30,
) -> tuple[int, dict[str, str], bytes]:
    """One request with exactly these headers (http.client adds Host unless one is given)."""
    connection = http.client.HTTPConnection(*address, timeout=timeout)
    headers = dict(headers or {})
    skip_host = "Host" in headers
    connection.putrequest(method, path, skip_host=skip_host, skip_accept_encoding=True)
    for key, value in headers.items():
        connection.putheader(key, value)
    if body is not None:
        connection.putheader("Content-Length", str(len(body)))
    connection.endheaders(body)
    response = connection.getresponse()
    payload = response.read()
    connection.close()
    return response.status, dict(response.getheaders()), payload


def state(address) -> dict:
    status, _, payload = call(address, "GET", "/api/state")
    assert status == 200
    return json.loads(payload)


def test_requests_from_other_sites_are_refused_and_change_nothing(tmp_path):
    out = tmp_path / "records"
    with server(tmp_path, "overrides.episode.max_steps=2", f"out={out}") as address:
        host, port = address
        own = f"http://{host}:{port}"
        status, _, _ = call(
            address, "POST", "/api/step", b'{"action": 1}', {"Origin": own, "Content-Type": "application/json"}
        )
        assert status == 200  # the page's own requests pass
        before = state(address)
        assert before["step"] == 1
        attacks = [
            # a page elsewhere posting through the player's browser (a "simple" text/plain request needs no preflight)
            {"Origin": "http://evil.example", "Content-Type": "text/plain"},
            {"Origin": "null", "Content-Type": "text/plain"},
            {"Origin": f"http://localhost:{port + 1}"},  # another local server's page
            {"Origin": f"https://{host}:{port}"},
            {"Sec-Fetch-Site": "cross-site"},
            # DNS rebinding: the attacker's own name, now pointing at 127.0.0.1, stays in Host
            {"Host": f"rebind.evil.example:{port}"},
            {"Host": f"{host}:{port + 1}"},
        ]
        for headers in attacks:
            for path, body in (
                ("/api/step", b'{"action": 1}'),
                ("/api/reset", b'{"level": "1-2"}'),
                ("/api/state", None),
                ("/", None),
            ):
                status, _, payload = call(address, "POST" if body else "GET", path, body, headers)
                assert status == 403, (headers, path, status, payload)
                assert "refused" in json.loads(payload)["error"]
        after = state(address)
        assert after == before  # same episode, step, EVs and frame
        assert not (out / "episodes.csv").exists()  # the step that would end the episode never ran
        # a link on another site may open the page in a tab of its own, never in a frame
        navigate = {"Sec-Fetch-Site": "cross-site", "Sec-Fetch-Mode": "navigate"}
        status, headers, _ = call(address, "GET", "/", headers={**navigate, "Sec-Fetch-Dest": "document"})
        assert status == 200 and headers["X-Frame-Options"] == "DENY"
        assert call(address, "GET", "/", headers={**navigate, "Sec-Fetch-Dest": "iframe"})[0] == 403
        # names of this machine are fine, and the episode goes on where it was
        assert call(address, "GET", "/api/state", headers={"Host": f"localhost:{port}"})[0] == 200
        status, _, payload = call(
            address, "POST", "/api/step", b'{"action": 0}', {"Origin": f"http://localhost:{port}"}
        )
        assert status == 200 and json.loads(payload)["done"] is True


def test_head_options_nesting_and_methods(tmp_path):
    with server(tmp_path, f"out={tmp_path / 'records'}") as address:
        get_status, get_headers, page = call(address, "GET", "/")
        status, headers, payload = call(address, "HEAD", "/")
        assert (status, payload) == (200, b"") and get_status == 200
        assert headers["Content-Length"] == get_headers["Content-Length"] == str(len(page))
        assert call(address, "HEAD", "/api/step")[0] == 405
        status, headers, payload = call(address, "OPTIONS", "/api/step")
        assert (status, headers["Allow"], payload) == (204, "POST, OPTIONS", b"")
        assert "Access-Control-Allow-Origin" not in headers  # no cross-origin permission is ever granted
        assert call(address, "OPTIONS", "/api/state")[1]["Allow"] == "GET, HEAD, OPTIONS"
        assert call(address, "OPTIONS", "/nowhere")[0] == 404
        status, headers, payload = call(address, "DELETE", "/api/reset")
        assert status == 405 and headers["Allow"] == "POST, OPTIONS"
        deep = b"[" * 2000 + b"]" * 2000  # within the 4 KiB body limit, deeper than the parser recurses
        for body in (deep, b'{"action": ' + deep + b"}"):
            status, _, payload = call(address, "POST", "/api/step", body)
            assert status == 400 and "nested too deeply" in json.loads(payload)["error"]
        assert state(address)["step"] == 0


def test_records_name_their_session_and_time(tmp_path):
    out = tmp_path / "records"
    sessions = []
    for _ in range(2):  # the same participant comes back: episode indices start at 0 again
        with server(tmp_path, "overrides.episode.max_steps=1", f"out={out}") as address:
            first = state(address)["session"]
            call(address, "POST", "/api/step", b'{"action": 0}')
            sessions.append(first)
    rows = read_rows(out / "episodes.csv")
    assert [(r["participant"], r["episode"]) for r in rows] == [("p01", "0"), ("p01", "0")]
    assert [r["session"] for r in rows] == sessions and sessions[0] != sessions[1]
    for row in rows:
        assert re.fullmatch(r"\d{8}T\d{6}Z-[0-9a-f]{6}", row["session"])
        assert re.fullmatch(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\+00:00", row["ended_at"])


# ------------------------------------------------------------------------------------------------- start-up
def test_unwritable_records_fail_at_start_up(tmp_path, capsys):
    blocker = tmp_path / "a-file"
    blocker.write_text("not a directory")
    assert serve(PlaySettings(port=0, out=blocker / "records")) == 1
    assert f"cannot write records in {blocker / 'records'}" in capsys.readouterr().err
    # a records file from something else is not appended to
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "episodes.csv").write_text("policy,level,steps\nrandom,1-1,5\n")
    assert serve(PlaySettings(port=0, out=foreign)) == 1
    assert "holds other columns" in capsys.readouterr().err
    assert (foreign / "episodes.csv").read_text() == "policy,level,steps\nrandom,1-1,5\n"


def test_listening_beyond_this_machine_is_warned_about(tmp_path, capsys):
    assert is_loopback("127.0.0.1") and is_loopback("::1") and is_loopback("localhost")
    assert not is_loopback("0.0.0.0") and not is_loopback("192.168.1.5")
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    assert serve(PlaySettings(host="0.0.0.0", port=0, out=blocker / "x")) == 1  # warned, then stopped
    assert "WARNING: listening on 0.0.0.0, not on this machine only" in capsys.readouterr().err


def test_a_vanished_browser_leaves_no_traceback(capsys):
    class Gone(io.RawIOBase):
        def write(self, data):
            raise BrokenPipeError(32, "Broken pipe")

    handler = PlayHandler.__new__(PlayHandler)
    handler.request_version, handler.command, handler.requestline = "HTTP/1.1", "GET", "GET / HTTP/1.1"
    handler.client_address, handler.close_connection, handler.wfile = ("127.0.0.1", 1), False, Gone()
    handler.send_body(200, "text/plain", b"x" * 100)
    assert handler.close_connection is True
    server = PlayServer.__new__(PlayServer)
    try:
        raise ConnectionResetError(104, "Connection reset by peer")
    except ConnectionResetError:
        server.handle_error(None, ("127.0.0.1", 1))
    assert capsys.readouterr().err == ""


# ------------------------------------------------------------------------------------------------ hostile requests
def _alias_bomb(width: int) -> str:
    """A few hundred bytes of YAML whose aliases expand to ``width ** width`` strings."""
    lines = [f"a0: &a0 [{', '.join(['lol'] * width)}]"]
    lines += [f"a{i}: &a{i} [{', '.join([f'*a{i - 1}'] * width)}]" for i in range(1, width)]
    return "\n".join(lines) + f"\ndescription: *a{width - 1}\n"


def test_a_level_request_is_a_name_and_the_server_keeps_answering(tmp_path):
    bomb = tmp_path / "bomb.yaml"
    bomb.write_text(_alias_bomb(9))
    secret = tmp_path / "secret.yaml"
    secret.write_text("agent: {mass: the-secret-value}\n")
    with server(tmp_path, f"out={tmp_path / 'records'}") as address:
        before = state(address)
        latencies, failures, stop = [], [], threading.Event()

        def poll():
            while not stop.is_set():
                start = time.monotonic()
                try:
                    status = call(address, "GET", "/api/state", timeout=10)[0]
                except OSError as exc:
                    failures.append(repr(exc))
                    continue
                latencies.append(time.monotonic() - start)
                if status != 200:
                    failures.append(status)

        pollers = [threading.Thread(target=poll) for _ in range(3)]
        for thread in pollers:
            thread.start()
        try:
            for level in (str(bomb), str(secret), "../../../../" + str(secret)[1:], str(secret)[:-5], "1-1/x.yaml"):
                status, _, payload = call(
                    address, "POST", "/api/reset", json.dumps({"level": level}).encode(), timeout=10
                )
                error = json.loads(payload)["error"]
                assert status == 400 and error.startswith("unknown level"), (level, status, error)
                assert "the-secret-value" not in error
            time.sleep(0.5)
        finally:
            stop.set()
            for thread in pollers:
                thread.join()
        assert not failures and latencies, failures
        assert max(latencies) < 1.0, max(latencies)  # the bound: every request answered within a second
        assert state(address)["level"] == before["level"] == "1-1"


class _SlowSession:
    """Stands in for the play session: ``state`` waits until the test lets it answer."""

    def __init__(self):
        self.entered, self.release = threading.Event(), threading.Event()

    def state(self):
        self.entered.set()
        self.release.wait(30)
        return {"step": 0}


@contextmanager
def in_process(monkeypatch, idle_timeout: float, max_requests: int) -> Iterator[tuple[tuple[str, int], _SlowSession]]:
    # module settings rather than arguments, so that the test runs (and fails) on a server without them
    monkeypatch.setattr(play, "IDLE_TIMEOUT", idle_timeout, raising=False)
    monkeypatch.setattr(play, "MAX_REQUESTS", max_requests, raising=False)
    httpd = PlayServer("127.0.0.1", 0, b"<html></html>")
    httpd.session = _SlowSession()
    thread = threading.Thread(target=httpd.serve_forever, daemon=True)
    thread.start()
    try:
        yield httpd.server_address[:2], httpd.session
    finally:
        httpd.session.release.set()
        httpd.shutdown()
        httpd.server_close()


def test_idle_connections_are_closed(monkeypatch):
    with in_process(monkeypatch, idle_timeout=0.5, max_requests=4) as (address, _):
        with socket.create_connection(address) as idle:
            idle.settimeout(15)  # a hang is far longer than the 0.5 s asked for
            assert idle.recv(1) == b""  # the server closed it
        with socket.create_connection(address) as slow:  # a request line, then nothing
            slow.sendall(b"GET / HTTP/1.1\r\n")
            slow.settimeout(15)
            while slow.recv(4096):
                pass
        assert call(address, "GET", "/")[0] == 200  # still serving


def test_requests_beyond_the_bound_are_answered_503(monkeypatch):
    with in_process(monkeypatch, idle_timeout=10, max_requests=1) as (address, session):
        held = []
        holder = threading.Thread(target=lambda: held.append(call(address, "GET", "/api/state", timeout=30)))
        holder.start()
        assert session.entered.wait(10)  # the one request allowed is being answered
        status, headers, payload = call(address, "POST", "/api/step", b'{"action": 1}', timeout=5)
        assert status == 503 and headers["Retry-After"] == "1", (status, payload)
        assert "busy" in json.loads(payload)["error"]
        session.release.set()
        holder.join()
        assert held[0][0] == 200  # the request in progress was answered
        # many clients at once: every request is answered, 200 or 503, none reset
        answers, errors = [], []

        def client():
            for _ in range(5):
                try:
                    answers.append(call(address, "GET", "/api/state", timeout=30)[0])
                except OSError as exc:
                    errors.append(repr(exc))

        clients = [threading.Thread(target=client) for _ in range(40)]
        for thread in clients:
            thread.start()
        for thread in clients:
            thread.join()
        assert not errors and len(answers) == 200 and set(answers) <= {200, 503}, (errors, set(answers))
