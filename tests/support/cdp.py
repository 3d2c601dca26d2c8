"""Debian's Chromium driven over the Chrome DevTools Protocol (Playwright's own browser download is not reachable):
headless, a throw-away profile, one page; navigate, evaluate, click with real mouse events, reload, screenshot."""

from __future__ import annotations

import asyncio
import base64
import contextlib
import itertools
import json
import re
import tempfile
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import aiohttp

from tests.support.chromium import FLAGS, chromium_binary

#: Deadline of one protocol call, and the default of a wait for the page.
CALL_S = 20.0


class Page:
    def __init__(self, ws: aiohttp.ClientWebSocketResponse) -> None:
        self._ws = ws
        self._ids = itertools.count(1)
        self._pending: dict[int, asyncio.Future[dict[str, Any]]] = {}
        self._events: asyncio.Queue[dict[str, Any]] = asyncio.Queue()
        self._reader = asyncio.create_task(self._read(), name="cdp-reader")

    async def _read(self) -> None:
        async for msg in self._ws:
            doc = json.loads(msg.data)
            if "id" in doc:
                fut = self._pending.pop(doc["id"], None)
                if fut is not None and not fut.done():
                    fut.set_result(doc)
            else:
                self._events.put_nowait(doc)

    async def close(self) -> None:
        self._reader.cancel()
        await asyncio.gather(self._reader, return_exceptions=True)
        await self._ws.close()

    async def call(self, method: str, timeout_s: float = CALL_S, **params: Any) -> dict[str, Any]:
        i = next(self._ids)
        fut: asyncio.Future[dict[str, Any]] = asyncio.get_running_loop().create_future()
        self._pending[i] = fut
        await self._ws.send_str(json.dumps({"id": i, "method": method, "params": params}))
        async with asyncio.timeout(timeout_s):
            doc = await fut
        if "error" in doc:
            raise AssertionError(f"CDP {method}: {doc['error']}")
        return doc.get("result", {})

    async def evaluate(self, expression: str, timeout_s: float = CALL_S) -> Any:
        res = await self.call("Runtime.evaluate", timeout_s, expression=expression, returnByValue=True,
                              awaitPromise=True)
        if "exceptionDetails" in res:
            raise AssertionError(f"page: {expression}: {res['exceptionDetails']}")
        return res["result"].get("value")

    async def wait_for(self, expression: str, what: str, timeout_s: float = 60.0) -> Any:
        """The first truthy value of ``expression``, checked in the page every 5 ms (no round trip per check)."""
        value = await self.evaluate(
            "new Promise((resolve) => { const t0 = Date.now(); (function check() { let v = null;"
            f" try {{ v = ({expression}); }} catch (e) {{ v = null; }}"
            f" if (v) resolve(v); else if (Date.now() - t0 > {timeout_s * 1000:.0f}) resolve(null);"
            " else setTimeout(check, 5); })(); })", timeout_s + CALL_S)
        if not value:
            raise AssertionError(f"page: {what}: not within {timeout_s:g} s")
        return value

    async def _load(self) -> None:
        while (await self._events.get()).get("method") != "Page.loadEventFired":
            pass  # drain the page's other events until the load

    async def goto(self, url: str) -> None:
        await self.call("Page.enable")
        await self.call("Page.navigate", url=url)
        async with asyncio.timeout(CALL_S):
            await self._load()

    async def reload(self) -> None:
        while not self._events.empty():
            self._events.get_nowait()
        await self.call("Page.reload", ignoreCache=True)
        async with asyncio.timeout(CALL_S):
            await self._load()

    async def click(self, selector: str) -> None:
        """A real mouse click (pressed, released) in the middle of the element."""
        box = await self.evaluate(
            f"(() => {{ const e = document.querySelector({json.dumps(selector)});"
            " e.scrollIntoView({block: 'center'}); const r = e.getBoundingClientRect();"
            " return [r.x + r.width / 2, r.y + r.height / 2]; })()")
        x, y = box
        for kind in ("mousePressed", "mouseReleased"):
            await self.call("Input.dispatchMouseEvent", type=kind, x=x, y=y, button="left", clickCount=1)

    async def type_into(self, selector: str, text: str) -> None:
        await self.evaluate(f"document.querySelector({json.dumps(selector)}).focus()")
        await self.call("Input.insertText", text=text)

    async def screenshot(self, out: Path) -> Path:
        res = await self.call("Page.captureScreenshot", format="png", captureBeyondViewport=True)
        await asyncio.to_thread(out.write_bytes, base64.b64decode(res["data"]))
        return out


@contextlib.asynccontextmanager
async def browser(width: int = 1200, height: int = 900) -> AsyncIterator[Page]:
    """Headless Chromium with one page, closed (bounded) on exit."""
    with tempfile.TemporaryDirectory(prefix="rgse-cdp-") as profile:
        proc = await asyncio.create_subprocess_exec(
            chromium_binary(), *FLAGS, f"--user-data-dir={profile}", "--remote-debugging-port=0",
            f"--window-size={width},{height}", "about:blank",
            stdin=asyncio.subprocess.DEVNULL, stdout=asyncio.subprocess.DEVNULL, stderr=asyncio.subprocess.PIPE)
        try:
            assert proc.stderr is not None
            async with asyncio.timeout(30):
                while True:
                    line = (await proc.stderr.readline()).decode()
                    if not line:
                        raise AssertionError(f"chromium exited {await proc.wait()} before listening")
                    if m := re.search(r"DevTools listening on ws://([^/]+)/", line):
                        break
            drain = asyncio.create_task(proc.stderr.read(), name="chromium-stderr")
            async with aiohttp.ClientSession() as http:
                async with asyncio.timeout(10):
                    targets = await (await http.get(f"http://{m.group(1)}/json/list")).json()
                page_url = next(t["webSocketDebuggerUrl"] for t in targets if t["type"] == "page")
                ws = await http.ws_connect(page_url, max_msg_size=64 * 1024 * 1024)
                page = Page(ws)
                try:
                    yield page
                finally:
                    await page.close()
        finally:
            if proc.returncode is None:
                proc.terminate()
                try:
                    async with asyncio.timeout(10):
                        await proc.wait()
                except TimeoutError:
                    proc.kill()
                    await proc.wait()
            if "drain" in locals():
                await asyncio.gather(drain, return_exceptions=True)
