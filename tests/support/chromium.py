"""Headless Chromium for the report tests: installed by ``scripts/ensure-chromium.sh`` if missing (never skipped)."""

from __future__ import annotations

import functools
import subprocess
import tempfile
from collections import defaultdict
from html.parser import HTMLParser
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync")


@functools.cache
def chromium_binary() -> str:
    proc = subprocess.run(["sh", str(REPO / "scripts" / "ensure-chromium.sh")], capture_output=True, text=True,
                          timeout=600, check=False)
    if proc.returncode != 0 or not proc.stdout.strip():
        pytest.fail(f"chromium is required for the report tests and could not be provided:\n{proc.stderr}")
    return proc.stdout.strip().splitlines()[-1]


def _run(args: list[str]) -> subprocess.CompletedProcess[str]:
    with tempfile.TemporaryDirectory(prefix="rgse-chromium-") as profile:
        cmd = [chromium_binary(), *FLAGS, f"--user-data-dir={profile}", *args]
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=60, check=False)
    if proc.returncode != 0:
        pytest.fail(f"chromium exited {proc.returncode}: {proc.stderr[-2000:]}")
    return proc


def dump_dom(page: Path) -> str:
    """The DOM after the page's load handlers ran (virtual time lets the load event fire before the dump)."""
    proc = _run(["--run-all-compositor-stages-before-draw", "--virtual-time-budget=5000", "--dump-dom",
                 page.resolve().as_uri()])
    return proc.stdout


def screenshot(page: Path, out: Path, height: int = 3000) -> Path:
    _run(["--hide-scrollbars", f"--window-size=1200,{height}", f"--screenshot={out}", page.resolve().as_uri()])
    return out


class Dom(HTMLParser):
    """Collects ``<img>`` attributes, ``data-field`` values and the text shown by each numbered element."""

    def __init__(self, text: str) -> None:
        super().__init__(convert_charrefs=True)
        self.images: list[dict[str, str | None]] = []
        self.fields: dict[str, list[str]] = defaultdict(list)
        self.shown: dict[str, list[str]] = defaultdict(list)
        self.body: dict[str, str | None] = {}
        self._open: list[str] = []
        self.feed(text)

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        a = dict(attrs)
        if tag == "img":
            self.images.append(a)
        if tag == "body":
            self.body = a
        if "data-field" in a:
            self.fields[a["data-field"] or ""].append(a.get("data-value") or "")
            self._open.append(a["data-field"] or "")
            self.shown[a["data-field"] or ""].append("")

    def handle_data(self, data: str) -> None:
        for f in self._open:
            self.shown[f][-1] += data

    def handle_endtag(self, tag: str) -> None:
        if tag in ("span", "code") and self._open:
            self._open.pop()
