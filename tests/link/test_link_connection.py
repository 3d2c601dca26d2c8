"""Connection and pool against a tiny codec-based server over real sockets: happy path and every fault kind."""

from __future__ import annotations

import asyncio
import socket

import pytest

from rgse_daemon.config import ControllerConfig, Protocol
from rgse_daemon.errors import LinkClosed, LinkTimeout, ProtocolError, VariableError
from rgse_daemon.link import frames as f
from rgse_daemon.link.connection import Connection, ConnectionState, LinkStats
from rgse_daemon.link.pool import LinkPool
from tests.support.link_miniserver import MiniServer
from tests.support.polling import wait_until


def conn_for(srv: MiniServer, **kw) -> Connection:
    opts = {
        "connect_timeout_s": 2.0,
        "request_timeout_s": 0.3,
        "keepalive_s": 20.0,
        "reconnect_min_s": 0.01,
        "reconnect_max_s": 0.05,
        "seed": 1,
    }
    opts.update(kw)
    return Connection("127.0.0.1", srv.port, **opts)


async def test_read_write_round_trip() -> None:
    async with MiniServer() as srv, conn_for(srv) as conn:
        assert conn.state is ConnectionState.CONNECTED
        assert await conn.read_var("$OV_PRO") == "100"
        assert await conn.write_var("$OV_PRO", "35") == "35"
        assert await conn.read_var("$OV_PRO") == "35"
        assert conn.stats.requests == conn.stats.replies == 3
        assert sum(conn.stats.latency_counts) == 3
    assert conn.state is ConnectionState.CLOSED
    with pytest.raises(LinkClosed):
        await conn.read_var("$OV_PRO")


async def test_failed_and_empty_reads_are_variable_errors() -> None:
    async with MiniServer() as srv, conn_for(srv) as conn:
        with pytest.raises(VariableError) as ei:
            await conn.read_var("$NOPE")
        assert ei.value.name == "$NOPE"
        with pytest.raises(VariableError):
            await conn.write_var("$NOPE", "1")
        assert conn.state is ConnectionState.CONNECTED  # a refused variable is not a link failure
    async with MiniServer(kvp=True) as srv, conn_for(srv) as conn:
        with pytest.raises(VariableError, match="empty value"):  # KVP: empty value with success 1
            await conn.read_var("$NOPE")


async def test_stall_times_out_then_reconnects_cleanly() -> None:
    async with MiniServer() as srv, conn_for(srv) as conn:
        srv.fault = "stall"
        with pytest.raises(LinkTimeout):
            await conn.read_var("$OV_PRO")
        assert conn.stats.timeouts == 1
        assert conn.state is not ConnectionState.CONNECTED
        # the late reply must not be matched to the next request: a fresh socket answers it
        assert await conn.read_var("$MODE_OP") == "#T1"
        assert conn.stats.reconnects == 1
        assert srv.connections == 2


async def test_dropped_connection_is_counted_and_healed() -> None:
    async with MiniServer() as srv, conn_for(srv) as conn:
        srv.fault = "drop"
        with pytest.raises(LinkClosed):
            await conn.read_var("$OV_PRO")
        assert conn.stats.errors == 1
        assert await conn.read_var("$OV_PRO") == "100"
        assert conn.stats.reconnects == 1


@pytest.mark.parametrize("fault", ["garbage", "wrong_tag", "wrong_type"])
async def test_bad_replies_are_protocol_errors_and_drop_the_socket(fault: str) -> None:
    async with MiniServer() as srv, conn_for(srv) as conn:
        srv.fault = fault
        with pytest.raises(ProtocolError):
            await conn.read_var("$OV_PRO")
        assert conn.state is ConnectionState.DISCONNECTED
        assert await conn.read_var("$OV_PRO") == "100"
        assert srv.connections == 2


async def test_cancelled_caller_does_not_corrupt_the_stream() -> None:
    async with MiniServer() as srv, conn_for(srv, request_timeout_s=5.0) as conn:
        srv.fault = "stall"
        task = asyncio.create_task(conn.read_var("$OV_PRO"))
        await wait_until(lambda: len(srv.requests) >= 1, "request reached the server")
        task.cancel()
        with pytest.raises(asyncio.CancelledError):
            await task
        assert conn.state is ConnectionState.DISCONNECTED
        assert await conn.read_var("$MODE_OP") == "#T1"


async def test_requests_are_serialised_on_one_connection() -> None:
    async with MiniServer() as srv, conn_for(srv) as conn:
        srv.variables.update({f"RGSE_V{i}": str(i) for i in range(30)})
        got = await asyncio.gather(*(conn.read_var(f"RGSE_V{i}") for i in range(30)))
        assert got == [str(i) for i in range(30)]
        assert srv.connections == 1


async def test_keepalive_pings_while_idle() -> None:
    async with MiniServer() as srv, conn_for(srv, keepalive_s=0.02) as conn:
        await wait_until(lambda: conn.stats.keepalives >= 2, "two keep-alives")
        assert f.ReadVarAscii("PING") in srv.requests


async def test_connect_refused_backs_off_and_maintainer_heals() -> None:
    with socket.socket() as s:  # a port with nobody listening
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    conn = Connection(
        "127.0.0.1",
        port,
        connect_timeout_s=1.0,
        request_timeout_s=0.5,
        reconnect_min_s=0.01,
        reconnect_max_s=0.04,
        seed=3,
    )
    with pytest.raises(LinkClosed):
        await conn.start()
    assert conn.state is ConnectionState.BACKOFF
    assert conn.stats.connect_failures == 1
    await conn.close()
    # the maintainer reconnects a dropped connection without traffic
    async with MiniServer() as srv, conn_for(srv) as conn2:
        srv.fault = "drop"
        with pytest.raises(LinkClosed):
            await conn2.read_var("$OV_PRO")
        await wait_until(lambda: conn2.state is ConnectionState.CONNECTED, "maintainer reconnected")
        assert conn2.stats.reconnects == 1


async def test_close_during_a_connect_in_flight_keeps_no_socket_open() -> None:
    """close() does not wait for the lock: a request that is connecting meanwhile must not bring the closed
    connection back to life with a socket nobody closes (it lingered until the garbage collector warned of an
    unclosed StreamWriter, in whichever test was running then)."""
    async with MiniServer() as srv:
        conn = conn_for(srv)  # never started: the first request connects
        task = asyncio.create_task(conn.read_var("$OV_PRO"))
        await asyncio.sleep(0)  # the request runs until it waits inside open_connection
        assert conn.state is ConnectionState.CONNECTING
        await conn.close()
        with pytest.raises(LinkClosed, match="closed while it was connecting"):
            await task
        assert conn.state is ConnectionState.CLOSED
        await wait_until(lambda: srv.connections == 1 and srv.open_connections == 0, "the server saw the close")
        assert srv.requests == []


async def test_close_during_a_backoff_wait_keeps_no_socket_open() -> None:
    """A request that waits out the backoff when close() comes gives up instead of connecting afterwards."""
    with socket.socket() as s:  # a port with nobody listening: the first connect fails and a backoff begins
        s.bind(("127.0.0.1", 0))
        refused_port = s.getsockname()[1]
    async with MiniServer() as srv:
        conn = Connection("127.0.0.1", refused_port, connect_timeout_s=2.0, request_timeout_s=5.0,
                          reconnect_min_s=0.2, reconnect_max_s=0.4, seed=1)
        with pytest.raises(LinkClosed):
            await conn.start()
        assert conn.state is ConnectionState.BACKOFF
        conn.port = srv.port  # the next attempt would succeed
        task = asyncio.create_task(conn.read_var("$OV_PRO"))
        await asyncio.sleep(0)  # the request is waiting out the backoff (0.1-0.2 s)
        await conn.close()
        with pytest.raises(LinkClosed, match="connection closed"):
            await task
        assert conn.state is ConnectionState.CLOSED
        assert srv.connections == 0


async def test_a_failed_connect_during_close_leaves_the_connection_closed() -> None:
    """A connect that fails after close() does not turn the closed connection into one that backs off and retries."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        refused_port = s.getsockname()[1]
    conn = Connection("127.0.0.1", refused_port, connect_timeout_s=2.0, request_timeout_s=0.5,
                      reconnect_min_s=0.01, reconnect_max_s=0.04, seed=1)
    task = asyncio.create_task(conn.read_var("$OV_PRO"))
    await asyncio.sleep(0)
    await conn.close()
    with pytest.raises(LinkClosed):
        await task
    assert conn.state is ConnectionState.CLOSED


def test_backoff_is_exponential_jittered_and_capped() -> None:
    conn = Connection("127.0.0.1", 1, reconnect_min_s=0.1, reconnect_max_s=1.0, seed=7)
    for failures, cap in [(1, 0.1), (2, 0.2), (3, 0.4), (4, 0.8), (5, 1.0), (12, 1.0)]:
        conn._failures = failures
        samples = [conn._backoff_s() for _ in range(50)]
        assert all(cap * 0.5 <= s <= cap for s in samples)
        assert len(set(samples)) > 1


def test_latency_histogram_buckets() -> None:
    st = LinkStats()
    for s in (0.0004, 0.0021, 0.0021, 0.5, 9.0):
        st.observe_latency(s)
    d = st.as_dict()["latency_histogram"]
    assert d["le_0.5ms"] == 1 and d["le_5ms"] == 2 and d["le_500ms"] == 1 and d["gt_2000ms"] == 1


# --- pool -----------------------------------------------------------------------------------------------------
def cfg_for(srv: MiniServer, **kw) -> ControllerConfig:
    base = {
        "host": "127.0.0.1",
        "port": srv.port,
        "request_timeout_s": 0.5,
        "reconnect_min_s": 0.01,
        "reconnect_max_s": 0.05,
        "pool_size": 4,
    }
    base.update(kw)
    return ControllerConfig(**base)


async def test_pool_detects_c3_and_snapshots_with_one_multi_read() -> None:
    async with MiniServer() as srv, LinkPool(cfg_for(srv)) as pool:
        assert pool.protocol is Protocol.C3BRIDGE
        srv.requests.clear()
        got = await pool.read_many(["$OV_PRO", "$MODE_OP", "$NOPE"])
        assert got["$OV_PRO"] == "100" and got["$MODE_OP"] == "#T1"
        assert isinstance(got["$NOPE"], VariableError)
        assert srv.requests == [f.ReadMulti(("$OV_PRO", "$MODE_OP", "$NOPE"))]
        assert pool.health()["protocol"] == "c3bridge"


async def test_pool_falls_back_to_single_reads_with_kvp() -> None:
    async with MiniServer(kvp=True) as srv, LinkPool(cfg_for(srv)) as pool:
        assert pool.protocol is Protocol.KVP
        srv.variables.update({f"RGSE_V{i}": str(i) for i in range(24)})
        srv.requests.clear()
        names = [f"RGSE_V{i}" for i in range(24)]
        got = await pool.read_many(names)
        assert got == {n: str(i) for i, n in enumerate(names)}
        assert all(isinstance(r, f.ReadVarAscii) for r in srv.requests) and len(srv.requests) == 24
        assert srv.connections == 4


async def test_pool_refuses_kvp_when_c3_is_configured() -> None:
    async with MiniServer(kvp=True) as srv:
        with pytest.raises(ProtocolError, match="PROXY_TYPE"):
            await LinkPool(cfg_for(srv, protocol="c3bridge")).start()


async def test_idle_connection_closed_by_peer_is_reopened_before_sending() -> None:
    async with MiniServer() as srv, conn_for(srv) as conn:
        srv.drop_all()
        await wait_until(lambda: conn._reader.at_eof(), "FIN reached the client's reader")
        assert await conn.write_var("$OV_PRO", "50") == "50"  # safe even for a write: nothing had been sent
        assert conn.stats.errors == 0 and conn.stats.reconnects == 1


async def test_pool_read_retries_once_after_peer_close() -> None:
    async with MiniServer() as srv, LinkPool(cfg_for(srv, pool_size=1)) as pool:
        srv.fault = "drop"
        assert await pool.read("$OV_PRO") == "100"
        assert pool.stats().errors == 1 and pool.stats().reconnects == 1


async def test_pool_closed_while_a_read_reconnects_keeps_no_socket_open() -> None:
    """The daemon's case: the controller link closes its pool (a stop, a lost link) while another job's read is
    reopening a connection the peer had closed; the read fails and the pool holds no socket afterwards."""
    async with MiniServer() as srv:
        pool = LinkPool(cfg_for(srv, pool_size=1))
        await pool.start()
        srv.drop_all()
        (conn,) = pool._conns
        await wait_until(lambda: conn._reader.at_eof(), "FIN reached the client's reader")
        task = asyncio.create_task(pool.read("$OV_PRO"))
        await asyncio.sleep(0)  # the read found the connection closed by the peer and is reconnecting
        assert pool.health()["connections"] == {"link0": "connecting"}
        await pool.close()
        with pytest.raises(LinkClosed):
            await task
        assert pool.health()["connections"] == {"link0": "closed"}
        await wait_until(lambda: srv.open_connections == 0, "no connection left open")
        assert srv.connections == 2  # the first one, and the reconnect that was closed at once
