"""aiomqtt's client, made to leave nothing behind: what the daemon's bridge (:mod:`rgse_daemon.io.mqtt`), the
operator's client (:mod:`rgse_daemon.io.operator`) and ``rgse doctor``'s broker check share.

aiomqtt (2.5) has two defects that bite every user of it here:

* **The reason of a lost connection is left unread.** When the broker drops the session (another client took the
  client id over, a broker restart, a broken network) aiomqtt sets ``MqttCodeError('Unexpected disconnection')`` on a
  future of the client (``_disconnected``) and reads it only in a message iteration or a publish that fails at once.
  A session that ends otherwise — a subscribe or publish that waits for an ack until its deadline, a stop — leaves it
  unread (``Client.__aexit__`` only asks whether the future is done), and asyncio logs "Future exception was never
  retrieved" with a traceback when the client is collected. The reason itself is no news: whoever used the session
  got its own error. :class:`Client` has it read whenever it is set.
* **A connect given up is left open.** ``Client.__aenter__`` runs paho's blocking connect (TCP, TLS handshake, CONNECT
  queued) in an executor thread, then waits for the CONNACK. A cancellation (a stop, a caller's deadline) does not
  stop that thread: it connects anyway, and aiomqtt then reads and pings the new socket (its misc task) with nobody
  left to close it. A CONNACK that does not come within the client's timeout fails ``__aenter__`` but leaves the
  socket open and the misc task running, until the keepalive runs out. And a CONNACK wait cancelled by asyncio
  leaves a cancelled future that aiomqtt's disconnect callback reads later ("Exception in callback", the socket not
  closed). :func:`enter` (and :func:`connection` around it) closes such a connection, bounded.
* **A cancellation can be lost.** Every wait of aiomqtt for the broker (the PUBACK of a publish, SUBACK, UNSUBACK,
  CONNACK, the disconnect) goes through ``Client._wait_for``, which is ``asyncio.wait_for``. On Python 3.11, a task
  cancelled in the loop iteration in which the awaited ack has just arrived gets the result and not the cancellation
  (CPython issue #86296, bpo-42130; fixed in 3.12, whose ``wait_for`` is built on ``asyncio.timeout``): it runs on
  as if never cancelled. Seen as the bridge's state sender, cancelled by a stop just as the PUBACK of its last
  state came, waiting on for the next snapshot, so that the session never ended, its retained "offline" was never
  published and the stop was cancelled at its deadline. :class:`Client` waits with ``asyncio.timeout`` instead.

Public API::

    client = Client(host, port, **aiomqtt_client_kwargs)        # in the running loop, as aiomqtt.Client
    await enter(client, close_s=..., cancelled_close_s=...)      # instead of await client.__aenter__()
    async with connection(client, close_s=...) as client: ...    # instead of async with client: ...
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import ssl
from collections.abc import AsyncIterator, Awaitable, Callable
from typing import Any, Self, TypeVar

import aiomqtt
import paho.mqtt.client as paho

from rgse_daemon.config import MqttConfig
from rgse_daemon.errors import ConfigError

log = logging.getLogger(__name__)

T = TypeVar("T")


def _read_exception(fut: asyncio.Future[Any]) -> None:
    """A done callback that reads a future's exception, so that it counts as retrieved."""
    if not fut.cancelled():
        fut.exception()


def _retrieve_disconnect_reason(client: aiomqtt.Client) -> None:
    """Have the reason aiomqtt (2.5) gives for an unexpected disconnection (``Client._disconnected``) read whenever it
    is set (module docstring)."""
    disconnected = getattr(client, "_disconnected", None)
    if isinstance(disconnected, asyncio.Future):
        disconnected.add_done_callback(_read_exception)


#: aiomqtt's method (2.5) that ``Client.__aenter__`` runs in an executor thread: paho's blocking connect (TCP, TLS
#: handshake, CONNECT queued). :class:`Client` overrides it to learn when it returns. Should an aiomqtt upgrade
#: rename it, the override is never called and :func:`_close_unentered` falls back to waiting for ``__aenter__``
#: itself (correct, but a connect given up then waits up to the client's timeout for the CONNACK wait to time out);
#: ``tests/mqtt/test_mqtt_connect_teardown.py`` fails on such a rename.
_THREADED_CONNECT = "_client_connect"
_CONNECT_RETURN_SEEN = callable(getattr(aiomqtt.Client, _THREADED_CONNECT, None))


#: aiomqtt's method (2.5) through which all its waits for the broker go (above); :class:`Client` overrides it.
#: ``tests/mqtt/test_mqtt_connect_teardown.py`` fails should an aiomqtt upgrade rename it.
_WAIT_FOR = "_wait_for"


def _set_none(fut: asyncio.Future[None]) -> None:
    if not fut.done():
        fut.set_result(None)


class Client(aiomqtt.Client):
    """aiomqtt's client, whose disconnect reason is always read, telling when the connect it runs in an executor
    thread has returned (``connect_returned``).

    A cancellation of ``__aenter__`` does not stop that thread. Knowing when it has returned lets :func:`enter` close
    the connection it made once it exists, and not before (paho is not meant to be disconnected from the loop while
    its connect runs in another thread).
    """

    def __init__(self, hostname: str, port: int = 1883, **kwargs: Any) -> None:
        super().__init__(hostname, port, **kwargs)
        #: ``host:port``, for messages.
        self.where = f"{hostname}:{port}"
        self._rgse_loop = asyncio.get_running_loop()
        #: Done once the threaded connect has returned or raised. Set through ``call_soon_threadsafe``, after the
        #: callbacks the thread scheduled before it (aiomqtt's socket reader, the creation of its misc task).
        self.connect_returned: asyncio.Future[None] = self._rgse_loop.create_future()
        _retrieve_disconnect_reason(self)

    def _client_connect(self) -> None:  # runs in aiomqtt's executor thread
        try:
            super()._client_connect()
        finally:
            with contextlib.suppress(RuntimeError):  # the loop was closed meanwhile: nobody is left to tell
                self._rgse_loop.call_soon_threadsafe(_set_none, self.connect_returned)

    async def _wait_for(self, fut: Awaitable[T], timeout: float | None) -> T:  # noqa: ASYNC109 (aiomqtt's signature)
        """aiomqtt's (2.5) ``_wait_for`` (``timeout`` None: the client's; ``math.inf``: none; past it
        ``aiomqtt.MqttError("Operation timed out")``), with ``asyncio.timeout`` for ``asyncio.wait_for``: a cancellation
        that arrives with the ack is raised, not lost (module docstring)."""
        if timeout is None:
            timeout = self.timeout
        try:
            async with asyncio.timeout(None if timeout == math.inf else timeout):
                return await fut
        except TimeoutError:
            raise aiomqtt.MqttError("Operation timed out") from None

    async def __aenter__(self) -> Self:
        await super().__aenter__()
        _retrieve_disconnect_reason(self)  # aiomqtt replaces the future when it was already done
        return self

    def _on_disconnect(self, *args: Any, **kwargs: Any) -> None:  # paho's callback, as aiomqtt (2.5) registers it
        """aiomqtt's, except when the CONNACK wait was cancelled: a connect that never completed has no disconnection
        to report (aiomqtt returns early for one that failed), and aiomqtt's ``_connected.exception()`` raised
        ``CancelledError`` inside paho's callback, before paho closed the socket — which then stayed open. The wait is
        cancelled by aiomqtt's own CONNACK timeout (:meth:`_wait_for` cancels the future, and aiomqtt replaces it only
        a loop iteration later) or by :func:`_close_when_returned`; when the caller gives up within a millisecond of
        that timeout (a deadline equal to the client's timeout, as the operator's), the DISCONNECT that closes the
        connection is written in between."""
        connected = getattr(self, "_connected", None)
        if isinstance(connected, asyncio.Future) and connected.cancelled():
            return
        super()._on_disconnect(*args, **kwargs)


def _misc_task(client: aiomqtt.Client) -> asyncio.Task[Any] | None:
    """aiomqtt's (2.5) task that runs paho's periodic work while a socket is open (``Client._misc_task``); aiomqtt
    cancels it when paho closes the socket."""
    task = getattr(client, "_misc_task", None)
    return task if isinstance(task, asyncio.Task) else None


def _paho_client(client: aiomqtt.Client) -> paho.Client | None:
    """The paho client under aiomqtt's (2.5, ``Client._client``)."""
    inner = getattr(client, "_client", None)
    return inner if isinstance(inner, paho.Client) else None


def _warn(message: str) -> None:
    log.warning("%s", message)


async def enter(client: Client, *, close_s: float, cancelled_close_s: float | None = None,
                on_not_closed: Callable[[str], None] = _warn) -> None:
    """``await client.__aenter__()`` (connect, wait for the CONNACK), except that a connect given up leaves nothing.

    ``__aenter__`` runs shielded, in a task of its own. When it fails (no CONNACK within the client's timeout, refused)
    or the caller is cancelled (a stop, a deadline), what it made is closed (:func:`_close_unentered`) within
    ``close_s`` — ``cancelled_close_s`` after a cancellation, if given — and the error or the cancellation is re-raised
    once that is done. A cancellation arriving while a failed connect is closed waits for that close (it is bounded);
    a further one does not wait, and the close goes on without it. When the close did not finish in time (the connect
    thread blocks on, up to paho's connect timeout), ``on_not_closed`` is told (a warning by default); the connection
    is then closed as soon as that thread returns.
    """
    entering = asyncio.create_task(client.__aenter__(), name=f"mqtt connect {client.where}")
    entering.add_done_callback(_read_exception)  # whoever gave up on it, its failure counts as read
    try:
        await asyncio.shield(entering)
    except BaseException as exc:
        timeout_s = close_s
        if isinstance(exc, asyncio.CancelledError) and cancelled_close_s is not None:
            timeout_s = cancelled_close_s
        closing = asyncio.create_task(_close_unentered(client, entering, timeout_s),
                                      name=f"mqtt close {client.where}")
        try:
            closed = await asyncio.shield(closing)
        except asyncio.CancelledError:  # cancelled while a failed connect is closed: bounded, so wait for it
            await asyncio.wait([closing])
            raise
        if not closed:
            on_not_closed(f"mqtt {client.where}: the connection of a connect given up was not closed within "
                          f"{timeout_s:g} s; it will be once paho's connect returns")
        raise


@contextlib.asynccontextmanager
async def connection(client: Client, *, close_s: float, cancelled_close_s: float | None = None,
                     on_not_closed: Callable[[str], None] = _warn) -> AsyncIterator[Client]:
    """``async with client``, entered by :func:`enter` (same arguments): a connect given up leaves nothing open. The
    exit is aiomqtt's (DISCONNECT, bounded by the client's ``timeout``)."""
    await enter(client, close_s=close_s, cancelled_close_s=cancelled_close_s, on_not_closed=on_not_closed)
    try:
        yield client
    except BaseException as exc:
        await client.__aexit__(type(exc), exc, exc.__traceback__)
        raise
    await client.__aexit__(None, None, None)


async def _close_unentered(client: Client, entering: asyncio.Task[Any], timeout_s: float) -> bool:
    """Close what a connect given up left behind: ``entering`` is the client's ``__aenter__`` (shielded), and its
    caller stops waiting for it (a cancellation) or it failed (no CONNACK within the timeout, refused). Waits at most
    ``timeout_s``; returns whether all was closed by then.

    aiomqtt itself leaves the connection open in both cases: a cancelled ``__aenter__`` leaves its connect thread
    running, and one that fails after the socket was opened (a CONNACK timeout) does not close that socket. So, by
    callbacks (:func:`_close_when_returned`, which go on if the deadline passes or this wait is cancelled): once the
    connect thread has returned, have paho send DISCONNECT and close the socket (aiomqtt then removes its reader and
    ends its misc task), and only then cancel ``entering`` if it still waits for the CONNACK. In that order because
    cancelling that wait cancels aiomqtt's ``_connected`` future, and aiomqtt's disconnect callback reads its
    ``.exception()``: with the socket still open, the close raised ``CancelledError`` inside paho's callback (asyncio
    logged "Exception in callback") and the socket stayed open. (aiomqtt's own CONNACK timeout can cancel that future
    in between all the same: :meth:`Client._on_disconnect` tolerates it.)
    """
    _close_when_returned(client, entering)
    try:
        async with asyncio.timeout(timeout_s):
            await asyncio.wait([entering])
            misc = _misc_task(client)
            if misc is not None:
                await asyncio.wait([misc])
    except TimeoutError:
        return False  # the connect thread blocks on (up to paho's connect timeout); the callbacks close once it returns
    return True


def _close_when_returned(client: Client, entering: asyncio.Task[Any]) -> None:
    """Once the connect thread returns (without the override, once ``__aenter__`` ends), disconnect; once the socket
    is closed (aiomqtt's misc task has ended), cancel the CONNACK wait (a no-op when it has ended)."""
    paho_client = _paho_client(client)

    def returned(_: asyncio.Future[Any]) -> None:
        if paho_client is not None:
            paho_client.disconnect()  # without a socket (the connect failed) a no-op
        misc = _misc_task(client)
        if misc is None or misc.done():
            entering.cancel()
        else:
            misc.add_done_callback(lambda _: entering.cancel())

    (client.connect_returned if _CONNECT_RETURN_SEEN else entering).add_done_callback(returned)


class _ClosingTlsContext(ssl.SSLContext):
    """An SSL context that closes the socket when the TLS handshake fails.

    paho-mqtt (2.2, ``Client._ssl_wrap_socket``) wraps the TCP socket with ``do_handshake_on_connect=False``
    and calls ``do_handshake()`` itself; when that raises (an unknown CA, a wrong host name) the socket is never
    closed — a descriptor leaked on every reconnect attempt against a misconfigured broker. Doing the handshake
    here, inside ``wrap_socket``, lets us close it; paho's own ``do_handshake()`` on the finished connection is
    then a no-op. The handshake is bounded by the TCP socket's timeout (paho's connect timeout).
    """

    def wrap_socket(self, sock: Any, *args: Any, **kwargs: Any) -> ssl.SSLSocket:  # type: ignore[override]
        ssl_sock = super().wrap_socket(sock, *args, **kwargs)
        try:
            ssl_sock.do_handshake()
        except BaseException:
            ssl_sock.close()
            raise
        return ssl_sock


def tls_context(cfg: MqttConfig) -> ssl.SSLContext | None:
    """What ``ssl.create_default_context`` gives a client (verify peer and host name), with the CA file if set."""
    if not cfg.tls:
        if cfg.tls_ca_file is not None:
            raise ConfigError("mqtt.tls_ca_file is set but mqtt.tls is false")
        return None
    ctx = _ClosingTlsContext(ssl.PROTOCOL_TLS_CLIENT)  # check_hostname and CERT_REQUIRED by default
    try:
        if cfg.tls_ca_file is None:
            ctx.load_default_certs(ssl.Purpose.SERVER_AUTH)
        else:
            ctx.load_verify_locations(cafile=str(cfg.tls_ca_file))
    except (OSError, ssl.SSLError) as exc:
        raise ConfigError(f"mqtt.tls_ca_file {cfg.tls_ca_file}: cannot load CA certificates: {exc}") from exc
    return ctx
