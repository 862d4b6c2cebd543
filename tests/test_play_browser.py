"""Human play (scripts/play.py) end to end: a person's key presses in a real headless Chromium, the JSON API's
refusals, the command line, and the episode rows it records for reports.

The browser tests drive Debian's chromium (``/usr/bin/chromium``, installed by scripts/setup.sh) through Playwright
and skip only where no chromium binary exists.  ``EVAAA_SAVE_SCREENSHOT=1`` saves the screenshot they take to
docs/images/play.png (for docs/play.md) instead of pytest's tmp dir.
"""

from __future__ import annotations

import json
import os
import shutil
import time
import urllib.error
import urllib.request
from collections.abc import Iterator
from pathlib import Path

import pytest
from helpers import load_script, play_server
from playwright.sync_api import Browser, Page, sync_playwright

from evaaa.play import PlaySettings
from evaaa.records import read_rows

ROOT = Path(__file__).resolve().parents[1]
SCREENSHOT = ROOT / "docs" / "images" / "play.png"
CHROMIUM = shutil.which("chromium")
#: as root in a container: no sandbox, no GPU, and /dev/shm may be tiny
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage"]


def request(url: str, method: str = "GET", body: bytes | None = None) -> tuple[int, dict]:
    """An HTTP request to the play server; returns the status and the decoded JSON answer."""
    req = urllib.request.Request(url, data=body, method=method, headers={"Content-Type": "application/json"})
    try:
        with urllib.request.urlopen(req, timeout=30) as response:
            return response.status, json.loads(response.read())
    except urllib.error.HTTPError as err:
        with err:
            return err.code, json.loads(err.read())


def step(url: str, action: int) -> dict:
    status, state = request(url + "api/step", "POST", json.dumps({"action": action}).encode())
    assert status == 200, state
    return state


# ------------------------------------------------------------------------------------------------- the browser
@pytest.fixture(scope="module")
def browser() -> Iterator[Browser]:
    if CHROMIUM is None:
        pytest.skip("no chromium binary on PATH: install Debian's chromium (bash scripts/setup.sh does, as root)")
    with sync_playwright() as playwright:
        # Debian's chromium, never a Playwright download (`playwright install` cannot reach its servers here)
        browser = playwright.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        yield browser
        browser.close()


@pytest.fixture
def page(browser: Browser) -> Iterator[Page]:
    page = browser.new_page(viewport={"width": 900, "height": 840})
    errors: list[str] = []
    page.on("pageerror", lambda exc: errors.append(str(exc)))
    yield page
    page.close()
    assert not errors, f"the page raised: {errors}"


def wait_for_step(page: Page, n: int) -> None:
    page.wait_for_function(f"document.getElementById('step').textContent === '{n}'")


def shown_evs(page: Page) -> dict[str, tuple[float, str]]:
    """Each EV bar's value and the number it displays."""
    rows = page.locator(".ev")
    return {
        rows.nth(i).get_attribute("data-name"): (
            float(rows.nth(i).get_attribute("data-value")),
            rows.nth(i).locator(".value").text_content(),
        )
        for i in range(rows.count())
    }


def test_a_person_plays_an_episode_in_the_browser_and_it_is_recorded(page, tmp_path):
    # default out= (outputs/human, relative to the working directory), so the page shows the path a user sees
    with play_server(tmp_path, "overrides.episode.max_steps=5") as url:
        page.goto(url)
        wait_for_step(page, 0)
        assert page.locator("#level-select").input_value() == "1-1"
        assert page.locator("#participant").text_content() == "tester"
        assert page.locator("#max-steps").text_content() == "5"
        # the 64x64 frame is shown at 384x384 with its pixels kept square
        size = page.eval_on_selector(
            "#frame", "e => [e.naturalWidth, e.getBoundingClientRect().width, getComputedStyle(e).imageRendering]"
        )
        assert size == [64, 384, "pixelated"]
        evs = shown_evs(page)
        assert set(evs) == {"satiation", "hydration", "temperature", "damage"}
        assert page.locator(".ev .range").first.text_content() == "viable [-15, 15]"
        frames = [page.get_attribute("#frame", "src")]

        page.keyboard.press("ArrowLeft")  # a turn changes the view wherever the agent stands
        wait_for_step(page, 1)
        frames.append(page.get_attribute("#frame", "src"))
        assert frames[1] != frames[0], "the view did not change after a turn"
        after = shown_evs(page)
        for name in ("satiation", "hydration"):  # both fall every decision
            assert after[name][0] < evs[name][0], f"{name} did not fall: {evs[name]} -> {after[name]}"
            assert after[name][1] != evs[name][1], f"the page still shows {name} {evs[name][1]}"

        page.keyboard.press("ArrowUp")
        wait_for_step(page, 2)
        page.keyboard.press("Space")
        wait_for_step(page, 3)
        page.keyboard.press("Period")
        wait_for_step(page, 4)
        page.check("#show-map")  # training levels offer the top-down map
        page.wait_for_function("document.getElementById('map').naturalWidth === 320")
        page.keyboard.press("ArrowRight")
        wait_for_step(page, 5)
        message = page.locator("#message")
        page.wait_for_function("document.getElementById('message').textContent.includes('MaxStepReached')")
        assert "outputs/human/episodes.csv" in message.text_content()
        page.wait_for_function("document.getElementById('map').complete")
        shot = SCREENSHOT if os.environ.get("EVAAA_SAVE_SCREENSHOT") == "1" else tmp_path / "play.png"
        shot.parent.mkdir(parents=True, exist_ok=True)
        page.screenshot(path=str(shot), full_page=True)
        assert shot.stat().st_size > 10_000

        page.keyboard.press("ArrowUp")  # an ended episode takes no more steps
        time.sleep(0.5)
        assert page.locator("#step").text_content() == "5"

        rows = read_rows(tmp_path / "outputs" / "human" / "episodes.csv")
        assert len(rows) == 1
        row = rows[0]
        assert (row["policy"], row["participant"], row["level"], row["episode"], row["seed"]) == (
            "human",
            "tester",
            "1-1",
            "0",
            "0",
        )
        assert (row["steps"], row["end_type"]) == ("5", "MaxStepReached")
        assert float(row["final_satiation"]) == pytest.approx(shown_evs(page)["satiation"][0])

        page.keyboard.press("Enter")  # a new episode
        wait_for_step(page, 0)
        assert page.locator("#episode").text_content() == "2"
        assert page.locator("#message").text_content() == "Press an arrow key to move."

        # leaving an unfinished episode for another level asks first: no keeps the episode, yes switches
        page.keyboard.press("ArrowLeft")
        wait_for_step(page, 1)
        page.once("dialog", lambda dialog: dialog.dismiss())
        page.select_option("#level-select", "1-2")
        assert page.locator("#level-select").input_value() == "1-1"
        assert page.locator("#step").text_content() == "1"
        page.once("dialog", lambda dialog: dialog.accept())
        page.select_option("#level-select", "1-2")
        page.wait_for_function("document.getElementById('description').textContent.startsWith('1-2')")
        wait_for_step(page, 0)
        assert len(read_rows(tmp_path / "outputs" / "human" / "episodes.csv")) == 1, "a left episode is not recorded"


def test_at_a_fixed_rate_the_agent_does_nothing_without_a_key(page, tmp_path):
    with play_server(tmp_path, "rate=10", "overrides.episode.max_steps=6", "out=records") as url:
        page.goto(url)
        wait_for_step(page, 0)
        assert "10 decisions per second" in page.locator("#pace").text_content()
        time.sleep(0.5)
        assert page.locator("#step").text_content() == "0", "the clock must wait for the player's first key"
        page.keyboard.press("ArrowLeft")  # one key; the five decisions after it are "do nothing"
        page.wait_for_function(
            "document.getElementById('message').textContent.includes('MaxStepReached')", timeout=20_000
        )
    rows = read_rows(tmp_path / "records" / "episodes.csv")
    assert [(r["steps"], r["end_type"], r["policy"]) for r in rows] == [("6", "MaxStepReached", "human")]


# ------------------------------------------------------------------------------------------------- the API
def test_the_api_refuses_bad_requests_and_keeps_serving(tmp_path):
    out = tmp_path / "records"
    with play_server(tmp_path, "overrides.episode.max_steps=3", f"out={out}", "seed=7") as url:
        refused = [
            ("POST", "api/step", b"{not json", 400, "malformed JSON"),
            ("POST", "api/step", b"[1]", 400, "expected a JSON object"),
            ("POST", "api/step", b"{}", 400, "action must be an integer in 0..4"),
            ("POST", "api/step", b'{"action": "1"}', 400, "got '1'"),
            ("POST", "api/step", b'{"action": 1.5}', 400, "got 1.5"),
            ("POST", "api/step", b'{"action": 1.0}', 400, "got 1.0"),
            ("POST", "api/step", b'{"action": true}', 400, "got True"),
            ("POST", "api/step", b'{"action": 5}', 400, "got 5"),
            ("POST", "api/step", b'{"action": -1}', 400, "got -1"),
            ("POST", "api/step", b'{"action": 1, "repeat": 3}', 400, "unknown field(s) repeat"),
            ("POST", "api/step", b"x" * 10_000, 413, "request body over"),
            ("POST", "api/reset", b'{"level": "no-such-level"}', 400, "available: 1-1, 1-2"),
            ("POST", "api/reset", b'{"level": 11}', 400, "unknown level 11"),
            ("POST", "api/reset", b'{"level": "/etc/passwd.yaml"}', 400, "unknown level '/etc/passwd.yaml'"),
            ("GET", "no/such/path", None, 404, "unknown path /no/such/path"),
            ("GET", "api/step", None, 405, "answers POST, not GET"),
            ("POST", "api/state", b"{}", 405, "answers GET, not POST"),
            ("DELETE", "api/reset", None, 405, "not DELETE"),
        ]
        for method, path, body, status, text in refused:
            got, answer = request(url + path, method, body)
            assert (got, text in answer.get("error", "")) == (status, True), (method, path, body, got, answer)

        # none of that moved the agent, and the server goes on serving
        status, state = request(url + "api/state")
        assert status == 200 and (state["level"], state["step"], state["done"]) == ("1-1", 0, False)
        assert state["low"] == [-15, -15, -15, 0] and state["high"] == [15, 15, 15, 100]
        assert state["frame"].startswith("data:image/png;base64,")
        for action in (1, 2):
            assert not step(url, action)["done"]
        state = step(url, 0)
        assert (state["step"], state["done"], state["end_type"]) == (3, True, "MaxStepReached")
        got, answer = request(url + "api/step", "POST", b'{"action": 1}')
        assert got == 409 and "POST /api/reset" in answer["error"]
        rows = read_rows(out / "episodes.csv")
        assert [(r["policy"], r["participant"], r["level"], r["seed"], r["steps"]) for r in rows] == [
            ("human", "tester", "1-1", "7", "3")
        ]

        with urllib.request.urlopen(url + "map.png", timeout=30) as response:
            assert response.headers["Content-Type"] == "image/png"
            assert response.read().startswith(b"\x89PNG")
        with urllib.request.urlopen(url, timeout=30) as response:
            assert b'id="frame"' in response.read()

        status, state = request(url + "api/reset", "POST", b"")  # no body: a new episode of the same level
        assert status == 200 and (state["level"], state["episode"], state["step"]) == ("1-1", 1, 0)
        status, state = request(url + "api/reset", "POST", b'{"level": "1-2"}')
        assert status == 200 and (state["level"], state["episode"], state["max_steps"]) == ("1-2", 1, 3)
        state = step(url, 4)
        assert state["step"] == 1 and state["level"] == "1-2"


# ------------------------------------------------------------------------------------------------- command line
def load_play():
    return load_script("play")


def test_the_command_line_reads_key_value_arguments():
    play = load_play()
    options = play.parse_args(
        [
            "level=1-2",
            "participant=07",
            "seed=3",
            "rate=5",
            "port=0",
            "host=::1",
            "out=somewhere",
            "overrides.episode.max_steps=5",
            "+overrides.agent.move_speed=10",
        ]
    )
    assert (options.level, options.participant, options.seed, options.rate, options.port, options.host) == (
        "1-2",
        "07",
        3,
        5.0,
        0,
        "::1",
    )  # participant 07 stays a string, as typed
    assert options.out == Path("somewhere")
    assert options.overrides == {"episode.max_steps": 5, "agent.move_speed": 10}
    assert play.parse_args([]) == PlaySettings()


@pytest.mark.parametrize(
    "args, expected",
    [
        (["level=no-such-level"], ["level=no-such-level: 'no-such-level' is not allowed", "allowed: 1-1, 1-2"]),
        (
            ["colour=red"],
            [
                "unknown key 'colour'",
                "keys: level, level_dir, participant, host, port, seed, rate, out, step_log, overrides",
            ],
        ),
        (["level"], ["'level' is not of the form key=value"]),
        (["port=http"], ["port=http: expected an integer"]),
        (["port=70000"], ["port=70000: expected a port in [0, 65535]"]),
        (["rate=-1"], ["rate=-1: expected a number in [0, 30]"]),
        (["participant=a b"], ["participant=a b: expected letters"]),
        (["step_log=maybe"], ["step_log=maybe: expected true or false"]),
        (["overrides.episode.max_steps=0"], ["overrides:", "episode.max_steps", "greater than or equal to 1"]),
        (["overrides.episode.nothing=1"], ["overrides:", "episode.nothing: unknown field"]),
        (["episode.max_steps=5"], ["unknown key 'episode.max_steps'"]),
    ],
)
def test_the_command_line_refuses_bad_arguments_before_serving(args, expected, capsys):
    assert load_play().main(args) == 2
    err = capsys.readouterr().err
    assert err.startswith("play.py: error: ") and err.count("\n") == 1, err  # one line
    for text in expected:
        assert text in err, err


def test_help_lists_the_keys_and_levels(capsys):
    assert load_play().main(["--help"]) == 0
    out = capsys.readouterr().out
    for text in (
        "level: str = 1-1",
        "participant: str = anonymous",
        "rate: float = 0.0",
        "port: int = 8000",
        "overrides.episode.max_steps=200",
        "1-1, 1-2",
    ):
        assert text in out
