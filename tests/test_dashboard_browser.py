"""The dashboard in a real browser: headless Chromium (Debian's ``chromium``) driven by Playwright against the real
CLI. Skipped when Chromium or Playwright is missing, unless ``SBAGENTS_REQUIRE_BROWSER=1`` (``.ci/run`` sets it)."""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.cli_helpers import default_sigint, popen
from tests.test_dashboard import RUN, write_run

REQUIRED = os.environ.get("SBAGENTS_REQUIRE_BROWSER") == "1"
CHROMIUM = os.environ.get("SBAGENTS_CHROMIUM") or shutil.which("chromium") or shutil.which("chromium-browser")

if not REQUIRED:
    pytest.importorskip("playwright.sync_api")
    if CHROMIUM is None:
        pytest.skip("no chromium on PATH (apt-get install chromium)", allow_module_level=True)
assert CHROMIUM is not None, "SBAGENTS_REQUIRE_BROWSER=1 but no chromium on PATH"

from playwright.sync_api import Browser, Page, expect, sync_playwright  # noqa: E402

TIMEOUT_MS = 60_000
expect.set_options(timeout=TIMEOUT_MS)


@pytest.fixture(scope="module")
def browser() -> Iterator[Browser]:
    with sync_playwright() as p:
        chromium = p.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox"])
        yield chromium
        chromium.close()


@pytest.fixture(scope="module")
def served(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[str, Path]]:
    logs = tmp_path_factory.mktemp("served") / "logs"
    write_run(logs)
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    env = {**os.environ, "PYTHONUNBUFFERED": "1", "SBAGENTS_CACHE_DIR": str(logs.parent / "cache")}
    # a subprocess on purpose: a real server the browser talks to while the tests run, stopped by Ctrl-C
    proc = subprocess.Popen([sys.executable, "-m", "sbagents.dashboard", "-f", str(logs), "--port", str(port)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
                            preexec_fn=default_sigint)
    assert proc.stdout is not None and "dashboard: http://" in proc.stdout.readline()
    yield f"http://127.0.0.1:{port}", logs
    proc.send_signal(signal.SIGINT)
    proc.communicate(timeout=30)


@pytest.fixture()
def page(browser: Browser) -> Iterator[Page]:
    # Playwright's wait_for_function evaluates its predicate in the page; under the dashboard's CSP (no
    # 'unsafe-eval') that can raise EvalError after a navigation, so the test context bypasses the CSP.
    context = browser.new_context(viewport={"width": 1280, "height": 900}, bypass_csp=True)
    tab = context.new_page()
    tab.set_default_timeout(TIMEOUT_MS)
    errors: list[str] = []
    tab.on("pageerror", lambda exc: errors.append(str(exc)))
    yield tab
    context.close()
    assert not errors, errors


def test_runs_page_then_a_run_with_its_chart(page: Page, served: tuple[str, Path]) -> None:
    base, _ = served
    page.goto(base + "/")
    row = page.locator(f'#runs tbody tr[data-id="0/{RUN}"]')
    expect(row).to_contain_text("ddpg")
    expect(row).to_contain_text("finished")
    row.get_by_role("link").click()
    page.wait_for_url(f"**/run/0/{RUN}")
    # plotly drew the training and evaluation traces as svg paths with data
    page.wait_for_function("document.querySelectorAll('#curves .scatterlayer .trace').length >= 3")
    points = page.evaluate("document.querySelectorAll('#curves .scatterlayer path.point').length")
    line = page.evaluate("document.querySelector('#curves .scatterlayer path.js-line').getAttribute('d')")
    assert points >= 6 and line.startswith("M") and "L" in line
    expect(page.locator("#command")).to_contain_text("python -m sbagents.train")
    expect(page.locator("#videos video")).to_have_count(1)


def test_decisions_violations_only_and_an_episode_timeline(page: Page, served: tuple[str, Path]) -> None:
    base, _ = served
    page.goto(f"{base}/decisions/0/{RUN}")
    expect(page.locator("#position")).to_contain_text("rows 1–50 of 60")
    page.locator("#violations").check()
    expect(page.locator("#position")).to_contain_text("9 matching rows")
    rows = page.locator("#decisions tbody tr")
    expect(rows).to_have_count(9)
    assert rows.evaluate_all("rows => rows.every(r => r.classList.contains('violation'))")
    cells = rows.evaluate_all("rows => rows.map(r => r.children[10].textContent)")
    assert cells == ["too_cold"] * 9
    rows.nth(0).locator("td.episode-link").click()
    expect(page.locator("#episode-title")).to_contain_text("episode 0")
    page.wait_for_function("document.querySelectorAll('#timeline .scatterlayer .trace').length >= 4")


def test_a_filtered_page_is_filled_from_where_the_scan_stopped(page: Page, served: tuple[str, Path]) -> None:
    """The server's time-boxed scan may return fewer matches than a page holds (rare violations in a big log): the
    page asks again from the returned cursor until it is full or the log ends. Here the first answer is cut to 3
    rows, as a scan that ran out of time would be."""
    import json
    from urllib.parse import parse_qs, urlparse

    base, _ = served
    requests: list[dict[str, list[str]]] = []

    def cut_first_filtered(route) -> None:  # type: ignore[no-untyped-def]
        query = parse_qs(urlparse(route.request.url).query)
        requests.append(query)
        if "violations" not in query or query.get("cursor") != ["0"]:
            route.continue_()
            return
        response = route.fetch(url=route.request.url.replace("count=50", "count=3"))
        route.fulfill(response=response, body=json.dumps(response.json()))

    page.route("**/api/decisions/**", cut_first_filtered)
    page.goto(f"{base}/decisions/0/{RUN}")
    expect(page.locator("#position")).to_contain_text("rows 1–50 of 60")
    page.locator("#violations").check()
    expect(page.locator("#position")).to_contain_text("9 matching rows")
    expect(page.locator("#position")).to_contain_text("end of log")
    expect(page.locator("#decisions tbody tr")).to_have_count(9)
    numbers = page.locator("#decisions tbody tr td:first-child").all_text_contents()
    assert [int(n) for n in numbers] == [i for i in range(60) if i % 7 == 3]
    assert any(q.get("count") == ["47"] for q in requests)  # the follow-up asked for the rest of the page


def test_trust_and_compare_pages_draw(page: Page, served: tuple[str, Path]) -> None:
    base, logs = served
    page.goto(f"{base}/trust/0/{RUN}")
    expect(page.locator("#safety")).to_contain_text("9 of 60 steps")
    page.wait_for_function("document.querySelectorAll('#adversarial .scatterlayer .trace').length == 1")
    page.wait_for_function("document.querySelectorAll('#fairness .barlayer .point').length == 2")
    page.wait_for_function("document.querySelectorAll('#epcost .scatterlayer path.point').length == 6")
    expect(page.locator("#safety")).to_contain_text("lagrangian, limit 1, multiplier 0.3")
    page.wait_for_function("document.querySelectorAll('#constraint .scatterlayer .trace').length == 3")
    write_run(logs, "ddpg/sbagents_SmartHome-v0_2", seed=3)
    page.goto(f"{base}/")
    page.locator(f'#runs input[data-id="0/{RUN}"]').check()
    page.locator('#runs input[data-id="0/ddpg/sbagents_SmartHome-v0_2"]').check()
    page.locator("#compare").click()
    page.wait_for_url("**/compare?run=*")
    page.wait_for_function("document.querySelectorAll('#cmp-0 .scatterlayer .trace').length >= 3")
    expect(page.locator("#cmp-0 .legend")).to_contain_text("mean of 2")


@pytest.mark.slow  # a real training run in a subprocess while the page follows it (~12-20 s here)
def test_a_training_run_appears_and_its_new_decisions_show(page: Page, served: tuple[str, Path]) -> None:
    base, logs = served
    before = set((logs / "ddpg").iterdir())
    # a subprocess on purpose: the run trains while the page follows it, and is stopped with Ctrl-C (SIGINT)
    train = popen("train", "--algo", "ddpg", "--env", "sbagents/SmartHome-v0", "-n", "5000", "-f", str(logs),
                  "--seed", "3", "--eval-freq", "0", "--transparency-log")
    try:
        deadline = time.monotonic() + 120
        while not (new := set((logs / "ddpg").iterdir()) - before) or not (min(new) / "transparency.csv").exists():
            assert time.monotonic() < deadline and train.poll() is None, "the training run wrote no log"
            time.sleep(0.2)
        run_id = f"0/ddpg/{min(new).name}"
        page.goto(base + "/")
        expect(page.locator(f'#runs tbody tr[data-id="{run_id}"]')).to_contain_text("running")
        page.goto(f"{base}/decisions/{run_id}?follow=1")
        expect(page.locator("#decisions tbody tr").first).to_be_visible()
        first_last = int(page.locator("#decisions tbody tr").last.locator("td").first.inner_text().replace(",", ""))
        page.wait_for_function(
            "n => { const r = document.querySelectorAll('#decisions tbody tr'); "
            "return r.length && Number(r[r.length - 1].children[0].textContent.replace(/,/g, '')) > n; }",
            arg=first_last,
        )
    finally:
        train.send_signal(signal.SIGINT)
        train.communicate(timeout=60)
