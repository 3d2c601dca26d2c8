"""The operator prompt is retained with QoS 1 (issue #16's leftover): a console or client that connects while a run
waits for the operator finds the prompt it missed, answers it, and the retained prompt then says nothing is pending.
The daemon on the simulated KR C4 and a private Mosquitto; the short campaign gives the prompts (a campaign that
cannot give a calibration, such as a zero and one mass point, is refused before its first prompt)."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path

from rgse_daemon.client import RgseClient, Run
from simulators.krc4.physics import campaign_point_payload
from simulators.krc4.sim import SimulatedKrc4
from tests.support.client import SHORT_CAMPAIGN
from tests.support.daemon import PREFIX, Events, daemon_config, first_of, running_daemon
from tests.support.mqtt import MosquittoProcess, retained
from tests.support.polling import wait_until


async def test_a_client_that_connects_during_a_prompt_finds_it_retained_and_answers_it(
        sim: SimulatedKrc4, private_broker: MosquittoProcess, tmp_path: Path) -> None:
    cfg = daemon_config(tmp_path / "data", controller_port=sim.port, share_dir=sim.share_dir,
                        broker_port=private_broker.port, loops=1)
    events = Events()
    async with running_daemon(cfg, on_event=events) as rd:
        await wait_until(lambda: rd.daemon.mqtt.connected, "mqtt connected")
        task = await rd.daemon.start_calibration(points=list(SHORT_CAMPAIGN))
        asked = await events.wait_for(lambda e: e.kind == "confirm", "the first prompt")
        # a fresh subscriber (the console reloading, a script started late) gets the prompt, QoS 1, retained
        await wait_until(lambda: rd.daemon.mqtt.counters.published > 3, "the prompt published")
        (msg,) = await first_of(_retained_prompt(private_broker, True), rd.task, "the retained prompt")
        doc = json.loads(msg.payload)
        assert msg.retain and msg.qos == 1
        assert doc["pending"] is True and doc["run_id"] == asked.run_id and doc["kind"] == "confirm"
        assert doc["data"]["point_index"] == 0 and doc["message"] == asked.message
        # the Python client, connected only now, sees the prompt once (not again from progress) and confirms it
        async with RgseClient.of(cfg) as rgse:
            run = Run(rgse, asked.run_id, "calibration")  # a script that knows the run (rgse run, the console)
            prompt = await run.next_prompt(10.0)
            assert prompt.point_index == 0 and prompt.message == asked.message
            sim.mount(campaign_point_payload(doc["data"]))
            await run.confirm(prompt, "mounted after a reconnect")
            second = await run.next_prompt(60.0)
            assert second.point_index == 1  # the next point's prompt, not the first one twice
            (msg,) = await _retained_prompt(private_broker, True)
            assert json.loads(msg.payload)["data"]["point_index"] == 1
            await run.abort("test over")
        await first_of(_ended(task), rd.task, "the run ends")
    # the run ended while it waited: nothing is pending any more
    (msg,) = await _retained_prompt(private_broker, False)
    assert json.loads(msg.payload)["pending"] is False


async def _retained_prompt(broker: MosquittoProcess, pending: bool) -> list:
    """The retained prompt once it says ``pending`` (the broker gets it from the daemon's queue a moment later)."""
    got: list = []

    async def check() -> bool:
        got[:] = await retained("127.0.0.1", broker.port, f"{PREFIX}/prompt")
        return len(got) == 1 and json.loads(got[0].payload).get("pending") is pending

    # a hang guard like tests.support.polling.wait_until's (whose predicate cannot await), not a timing check: 5 s
    # was one once, when the suite ran beside other work and the run's end took longer to reach the broker
    deadline = asyncio.get_running_loop().time() + 15.0
    while asyncio.get_running_loop().time() < deadline:
        if await check():
            return got
        await asyncio.sleep(0.05)
    raise AssertionError(f"no retained prompt with pending = {pending} within 15 s: {got!r}")


async def _ended(task: asyncio.Task) -> None:
    try:
        await task
    except Exception:  # aborted: what the test asked for
        return
