"""`fixbench report`'s report/index.html: self-contained (tables, figures as data URIs, provenance), and
rendered by headless Chromium with no console error and no request outside the file.

Chromium (Debian's package, /usr/bin/chromium) is driven over the DevTools protocol on a pipe
(``--remote-debugging-pipe``: JSON messages separated by NUL bytes on file descriptors 3 and 4), so
the test needs no driver package; it skips where Chromium is absent."""

from __future__ import annotations

import json
import os
import re
import select
import shutil
import subprocess
from pathlib import Path

import pytest
from test_report import fake_run

from fixbench.bench.records.store import Store
from fixbench.bench.reporting.report import make_report
from fixbench.bench.running.provenance import provenance

#: one xdist worker runs these tests (`make test`: --dist loadgroup), so the report is made once a session
pytestmark = pytest.mark.xdist_group("test_html")

CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"


@pytest.fixture(scope="module")
def page(tmp_path_factory) -> Path:
    run = fake_run(tmp_path_factory.mktemp("html") / "run")
    store = Store(run)
    for i, row in enumerate(sorted(store.finished().values(), key=lambda r: r["cell"])):
        if i % 2:  # half the rows with a provenance (the others as rows made before it was recorded)
            store.rewrite(dict(row, provenance=dict(provenance(), cpu="Test CPU <x>")))
    (run / "matrix.toml").write_text('name = "fake"\n# a <comment> & more\n')
    res = make_report(run, fields=False)
    assert res["html"] == run / "report" / "index.html"
    return res["html"]


def test_index_is_self_contained(page):
    text = page.read_text(encoding="utf-8")
    figures = sorted(p.name for p in (page.parent / "figures").glob("*.png"))
    assert len(figures) >= 4
    assert text.count('src="data:image/png;base64,') == len(figures)
    assert not re.search(r'(src|href)="(?!data:|#)', text)  # nothing outside the file
    assert "<script" not in text
    assert text.count("<table") >= 5 and ">planner</th>" in text
    assert "<h2>Provenance</h2>" in text and "Test CPU &lt;x&gt;" in text and "(9 cells)" in text
    assert "Not recorded for 9 cells" in text
    assert "# a &lt;comment&gt; &amp; more" in text


class _Chromium:
    """Headless Chromium driven over the DevTools protocol on a pipe."""

    def __init__(self, profile: Path):
        to_child, self._w = os.pipe()
        self._r, from_child = os.pipe()

        def fds():  # the child's fd 3 reads our messages, its fd 4 writes its own
            a, b = os.dup(to_child), os.dup(from_child)
            os.dup2(a, 3)
            os.dup2(b, 4)

        self.proc = subprocess.Popen([CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--no-first-run",
                                      "--remote-debugging-pipe", f"--user-data-dir={profile}"],
                                     preexec_fn=fds, close_fds=False, stdout=subprocess.DEVNULL,
                                     stderr=subprocess.DEVNULL)
        os.close(to_child)
        os.close(from_child)
        self._buf, self._id, self.events = b"", 0, []

    def send(self, method: str, params: dict | None = None, session: str | None = None) -> dict:
        self._id += 1
        msg = {"id": self._id, "method": method, "params": params or {}}
        if session:
            msg["sessionId"] = session
        os.write(self._w, json.dumps(msg).encode() + b"\0")
        reply = self.wait(lambda m: m.get("id") == self._id)
        assert "error" not in reply, reply
        return reply.get("result", {})

    def wait(self, done, timeout: float = 120.0) -> dict:
        """The first message for which ``done`` holds; the others are kept in ``events``."""
        while True:
            while b"\0" not in self._buf:
                if not select.select([self._r], [], [], timeout)[0]:
                    raise TimeoutError("no message from Chromium")
                chunk = os.read(self._r, 1 << 16)
                if not chunk:
                    raise EOFError("Chromium closed the pipe")
                self._buf += chunk
            raw, self._buf = self._buf.split(b"\0", 1)
            msg = json.loads(raw)
            if done(msg):
                return msg
            self.events.append(msg)

    def close(self) -> None:
        try:
            self.send("Browser.close")
        finally:
            self.proc.wait(timeout=60)
            os.close(self._w)
            os.close(self._r)


def render(path: Path, profile: Path) -> tuple[list[str], list[str], dict]:
    """Open ``path`` in headless Chromium: its console errors, the URLs it requested, and what the
    rendered page holds (images loaded, tables, title)."""
    chrome = _Chromium(profile)
    try:
        target = chrome.send("Target.createTarget", {"url": "about:blank"})["targetId"]
        s = chrome.send("Target.attachToTarget", {"targetId": target, "flatten": True})["sessionId"]
        for domain in ("Runtime", "Log", "Page", "Network"):
            chrome.send(f"{domain}.enable", session=s)
        chrome.send("Page.navigate", {"url": path.resolve().as_uri()}, session=s)
        chrome.wait(lambda m: m.get("method") == "Page.loadEventFired")
        state = chrome.send("Runtime.evaluate", {"returnByValue": True, "expression": (
            "({images: document.images.length, loaded: Array.from(document.images).filter("
            "i => i.complete && i.naturalWidth > 0).length, tables: document.querySelectorAll('table').length, "
            "title: document.title})")}, session=s)["result"]["value"]
    finally:
        chrome.close()
    errors, urls = [], []
    for m in chrome.events:
        p = m.get("params", {})
        if m.get("method") == "Runtime.exceptionThrown":
            errors.append(p["exceptionDetails"].get("text", "exception"))
        elif m.get("method") == "Runtime.consoleAPICalled" and p.get("type") in ("error", "assert"):
            errors.append(" ".join(str(a.get("value")) for a in p.get("args", [])))
        elif m.get("method") == "Log.entryAdded" and p["entry"]["level"] == "error":
            errors.append(p["entry"]["text"])
        elif m.get("method") == "Network.requestWillBeSent":
            urls.append(p["request"]["url"])
    return errors, urls, state


chromium = pytest.mark.skipif(not Path(CHROMIUM).is_file(), reason="Chromium is not installed (apt install chromium)")


@chromium
def test_index_renders_in_chromium_without_console_errors(page, tmp_path):
    errors, urls, state = render(page, tmp_path / "profile")
    assert errors == []
    assert urls and all(u.startswith(("file:", "data:")) for u in urls), urls
    assert state["images"] >= 4 and state["loaded"] == state["images"]
    assert state["tables"] >= 5 and state["title"].startswith("fixbench report")


@chromium
def test_the_console_check_sees_errors(tmp_path):
    """The same check on a page with a missing image and a script error reports both."""
    bad = tmp_path / "bad.html"
    bad.write_text('<!DOCTYPE html><html><head><meta charset="utf-8"><title>bad</title></head><body>'
                   '<img src="missing.png"><script>console.error("boom")</script></body></html>')
    errors, _, state = render(bad, tmp_path / "profile")
    assert "boom" in errors and any("Failed to load resource" in e for e in errors)
    assert state["loaded"] == 0
