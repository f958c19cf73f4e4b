"""Screenshots of the dashboard's pages for the README: ``python docs/make_screenshots.py -f LOGS -o docs/images``.

Serves ``LOGS`` with the dashboard's app in this process and photographs each page in headless Chromium
(Playwright driving Debian's ``chromium``; ``--chromium PATH`` for another one): the runs table; the newest run with
an adversarial evaluation (its curves, its trust view) and a comparison of every run of its env; the newest run with
a recorded video's decisions (its training log's violations, one episode's timeline beside the video).
"""

from __future__ import annotations

import argparse
import logging
import shutil
import threading
from pathlib import Path

from werkzeug.serving import make_server

from sbagents.dashboard.app import create_app
from sbagents.dashboard.folders import ServedFolders
from sbagents.dashboard.runs import RunCatalog


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("-f", "--log-folder", required=True)
    parser.add_argument("-o", "--output", default="docs/images")
    parser.add_argument("--chromium", default=shutil.which("chromium") or "chromium")
    args = parser.parse_args()
    from playwright.sync_api import sync_playwright

    logging.getLogger("werkzeug").setLevel(logging.ERROR)
    folders = ServedFolders.from_paths([args.log_folder])
    rows = RunCatalog(folders).rows()
    root = folders.roots[0]
    trust_run = next(r for r in rows if (root / r.id.partition("/")[2] / "adversarial.csv").exists())
    video_run = next((r for r in rows if list((root / r.id.partition("/")[2]).glob("videos/*.csv"))), trust_run)
    same_env = [r.id for r in rows if r.env == trust_run.env]
    server = make_server("127.0.0.1", 0, create_app(folders), threaded=True)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    base = f"http://127.0.0.1:{server.port}"
    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    video_log = next((root / video_run.id.partition("/")[2]).glob("videos/*.csv"), None)
    log_arg = f"?log=videos/{video_log.name}" if video_log else ""
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=args.chromium, args=["--no-sandbox"])
        page = browser.new_page(viewport={"width": 1280, "height": 800})
        shots = [
            ("runs", "/", None),
            ("run", f"/run/{trust_run.id}", "#curves .scatterlayer .trace"),
            ("trust", f"/trust/{trust_run.id}", "#fairness .hm, #fairness .barlayer .point"),
            ("compare", "/compare?" + "&".join(f"run={i}" for i in same_env), "#cmp-0 .scatterlayer .trace"),
        ]
        for name, path, ready in shots:
            page.goto(base + path)
            page.wait_for_selector(ready or "#runs tbody tr")
            page.wait_for_timeout(800)
            page.screenshot(path=str(out / f"dashboard-{name}.png"), full_page=True)
            print(out / f"dashboard-{name}.png")
        page.goto(f"{base}/decisions/{video_run.id}?violations=1")
        page.wait_for_selector("#decisions tbody tr")
        page.wait_for_timeout(1500)
        page.screenshot(path=str(out / "dashboard-violations.png"))
        print(out / "dashboard-violations.png")
        page.goto(f"{base}/decisions/{video_run.id}{log_arg}")
        page.wait_for_selector("#decisions tbody tr td.episode-link")
        page.locator("#decisions tbody tr td.episode-link").first.click()
        page.wait_for_selector("#timeline .scatterlayer .trace")
        page.wait_for_timeout(1500)
        box = page.locator("#timeline .nsewdrag").first.bounding_box()
        if box:  # hover a step: the video seeks to its frame
            page.mouse.move(box["x"] + box["width"] * 0.4, box["y"] + box["height"] * 0.5)
            page.wait_for_timeout(1500)
        page.locator("#episode").screenshot(path=str(out / "dashboard-decisions.png"))
        print(out / "dashboard-decisions.png")
        browser.close()
    server.shutdown()


if __name__ == "__main__":
    main()
