"""The regulated link, for Python controllers.

A :class:`Link` connects a base (the operator's side) and a remote (the
robot's side) over TCP. Each side sends one sample per period; the Network
Delay Regulator at each input releases the peer's samples at a constant
period, so the controller sees a constant, known delay::

    import ndr

    with ndr.Link.connect("127.0.0.1:7300", axes=2, period=0.01) as link:
        for tick in link.ticks():
            command = controller(tick.sample)     # float64 array, shape (2,)
            link.send(command)

The remote side listens; off loopback, over mutual TLS (``ndr keygen`` makes
each side's certificate; each pins the other's)::

    tls = ndr.TlsConfig("robot.crt", "robot.key", peer_cert="base.crt")
    with ndr.Link.listen("0.0.0.0:7300", axes=2, period=0.01, tls=tls) as listener:
        with listener.accept() as link:
            for tick in link.ticks():
                link.send(plant.step(tick.sample))

Waiting (``recv``, ``ticks``, ``accept``, ``connect``) releases the GIL and
can be interrupted with Ctrl-C. ``arecv`` and ``aticks`` do the same for
asyncio. Events (the link connected, started, paused, its delay changed,
it lost its peer, it closed: the Rust link's events) are logged to the
``ndr.link`` logger and kept for :meth:`Link.events`; Rust's own log records
reach the ``ndr.*`` loggers.

A robot may be shared: ``Link.listen(..., observers=N)`` serves one
controlling base and up to ``N`` observers, which connect with
``observe=True``; a base that connects with ``wait_for_control=SECONDS``
observes until control frees and is then granted it (``control_granted``),
and a controller gives control up with :meth:`Link.yield_control`. See
``docs/guide/sharing.md``.
"""

from __future__ import annotations

import asyncio
import logging
import os
import sys
import threading
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import (
    Any,
    AsyncIterator,
    Callable,
    Dict,
    Iterator,
    List,
    Optional,
    Sequence,
    Tuple,
    TypedDict,
    Union,
)

import numpy as np

from . import _native
from ._native import LinkClosedError, PeerClosedError, Tick, TlsConfig

__all__ = [
    "Event",
    "FloorStats",
    "LatenessStats",
    "Link",
    "LinkStats",
    "Listener",
    "ListenerStats",
    "RelayDatagramDirectionStats",
    "RelayDatagramStats",
    "RelayDirectionStats",
    "RelayStats",
    "RunningStats",
    "SharingStats",
    "Tick",
    "TlsConfig",
]

_log = logging.getLogger("ndr.link")

Address = Union[str, Tuple[str, int]]
SampleLike = Union[np.ndarray, Sequence[float], float]

# How long one slice of an asynchronous receive waits before it checks
# whether its task was cancelled.
_ASYNC_SLICE = 0.05


@dataclass(frozen=True)
class Event:
    """Something the controller should know about the link: one of the Rust
    link's events (``Event::kind`` in ``ndr-core``), no other.

    ``kind`` is one of:

    - ``"connected"``: the handshake succeeded (``details`` holds the peer's
      role, ``command_width``, ``state_width``, ``layout``, period and mode);
    - ``"started"``: samples flow, with ``period`` and ``ns`` (the
      regulators' nominal size); it comes again after each pause of the
      dynamic mode, with the new ``period`` and ``ns`` (``stats["resizes"]``
      counts those);
    - ``"paused"``: dynamic mode stops the flow to change ``period`` and
      ``ns``; ``"started"`` follows when samples flow again with them;
    - ``"delay_changed"``: a target-delay playout (``"adaptive"``, …)
      changed the constant delay it holds, now ``delay`` seconds, ``ticks``
      periods rounded up (no pause: the change is smooth; at periods over
      20 ms the adaptive delay moves in fractions of a period, and its
      samples are released between ticks);
    - ``"round_trip_changed"``: the round trip of this side's own samples,
      in whole periods, changed: ``ticks`` is ``ceil(grtt / period)`` of
      the release that follows, ``grtt`` that release's round trip in
      seconds (the first one measured is announced too). Under the adaptive
      playout it moves by a tick between ``"delay_changed"`` events as
      releases fall on either side of a tick; an underflow of the FIFO
      stretches it. A Smith predictor follows it (``set_round_trip``);
    - ``"link_lost"``: no fresh sample for the watchdog time
      (``silent_for``): hold the robot safely;
    - ``"link_restored"``: fresh samples flow again after ``"link_lost"``,
      ``outage`` seconds after the last fresh one; with ``reconnect=True``
      also when a new session's samples flow after the link lost its peer
      (``outage``: from the loss to the new session's start);
    - ``"closed"``: the link ended (``error`` says why; ``details["normal"]``
      is true when either side closed it in order).

    On a shared robot (``Link.listen(observers=N)``):

    - ``"control_granted"``: this link holds control from now, in control
      term ``term`` (a base's commands apply from its first of this term;
      on the remote, the link's base was granted it). A base given control
      at once gets it right after ``"connected"``;
    - ``"control_lost"``: a base lost control (``term``: the term it held),
      taken for another base or yielded: it observes from now, its commands
      are no longer sent;
    - ``"control_requested"``: a base that holds control: another base waits
      for it (:meth:`Link.yield_control` gives it up);
    - ``"control_yielded"``: on the remote, the link's base gave control up
      (``term``: the term it held);
    - ``"applied"``: an observer's link: the robot applied a command. ``term``
      and ``details``: ``seq`` (on its controller's link), ``sent_at`` and
      ``applied_at`` (when its controller sent it and when the robot applied
      it, both on the remote's clock), ``arrived_at`` (here, on this side's
      clock), and ``values`` (``Event.values``, a float64 array). They come
      at the controller's rate: read them with :meth:`Link.events` (or
      ``on_event``) often, or the oldest beyond 256 are dropped and
      counted (``events_dropped``).

    ``"connected"``'s ``details["seat"]`` is the seat the peer's Hello named
    (as :attr:`Link.peer_seat`).

    An underflow (the sample due at a tick had not arrived, the last one is
    repeated) is no event: the tick says it (``tick.status == "held"``) and
    the stats count it (``stats["underflows"]``, ``stats["released_held"]``).
    """

    kind: str
    period: Optional[float] = None
    ns: Optional[int] = None
    silent_for: Optional[float] = None
    outage: Optional[float] = None
    """A ``link_restored`` event's outage, in seconds."""
    delay: Optional[float] = None
    ticks: Optional[int] = None
    grtt: Optional[float] = None
    error: Optional[str] = None
    term: Optional[int] = None
    """The control term of a ``control_*`` or ``applied`` event."""
    values: Optional[np.ndarray] = field(default=None, compare=False)
    """An ``applied`` event's command, float64 of shape ``(command_width,)``."""
    details: Dict[str, Any] = field(default_factory=dict)


# The keyword arguments of Link.connect and Link.listen that configure the
# link, and the native settings' name for each.
_SETTINGS = {
    "role": "role",
    "axes": "axes",
    "command_width": "command_width",
    "state_width": "state_width",
    "period": "period",
    "regulation": "regulation",
    "underflow": "underflow",
    "watchdog": "watchdog",
    "liveness": "liveness",
    "handshake_timeout": "handshake_timeout",
    "queue": "app_queue",
    "insecure": "insecure",
    "transport": "transport",
    "realtime": "realtime",
    "rt_priority": "rt_priority",
    "rt_cpu": "rt_cpu",
    "observers": "observers",
    "observe": "observe",
    "wait_for_control": "wait_for_control",
}


class RunningStats(TypedDict):
    """A running summary of a measure, in seconds (count 0: the others 0)."""

    count: int
    mean: float
    std: float
    min: float
    max: float


class LatenessStats(TypedDict):
    """How late a hub met its deadlines, in seconds, over all its links."""

    count: int
    missed: int
    """Deadlines met a whole period late or more; a hub's (``lateness``,
    ``release_lateness``) counts those 1 ms late or more, whatever its links'
    periods."""
    min: float
    p50: float
    p99: float
    p999: float
    max: float
    mean: float


class RelayDirectionStats(TypedDict):
    """One direction of an :class:`ndr.Relay` (``forward``: towards the
    upstream)."""

    frames_received: int
    frames_delivered: int
    bytes_delivered: int
    held_back: int
    """Frames waiting for their delay now."""


class RelayDatagramDirectionStats(TypedDict):
    """One direction of an :class:`ndr.Relay`'s datagram path, summed over
    its flows (``forward``: towards the upstream)."""

    received: int
    lost: int
    """Dropped by the relay's loss model."""
    queue_full: int
    """Dropped because the direction's queue was full."""
    delivered: int
    bytes_delivered: int
    send_failed: int
    held_back: int
    """Sent later than their own delay, behind an earlier, slower one."""
    evicted: int
    """Dropped while they waited, their flow evicted for a new client."""


class RelayDatagramStats(TypedDict):
    """The datagram (UDP) path of an :class:`ndr.Relay`: one flow per client
    address."""

    flows_opened: int
    flows_active: int
    flows_refused: int
    """Datagrams from a new client dropped at the flow limit, every flow
    answered by the upstream and active."""
    flows_evicted: int
    """Flows the upstream never answered on, given to a new client at the
    flow limit."""
    flows_expired: int
    forward: RelayDatagramDirectionStats
    backward: RelayDatagramDirectionStats


class RelayStats(TypedDict):
    """The counters of an :class:`ndr.Relay` (``relay.stats``)."""

    connections: int
    active: int
    finished: int
    upstream_failures: int
    framing_errors: int
    """Connections cut for a frame the relay could not read."""
    queue_overflows: int
    io_errors: int
    closed_by_shutdown: int
    forward: RelayDirectionStats
    backward: RelayDirectionStats
    datagrams: RelayDatagramStats


class ListenerStats(TypedDict):
    """What a :class:`Listener` accepted and refused, by reason
    (``listener.stats``; the names of the Rust ``ListenerStats``)."""

    accepted: int
    """Links handed to the application."""
    refused_certificate: int
    refused_no_certificate: int
    refused_version: int
    """TLS: the peer does not speak TLS 1.3."""
    timeouts: int
    """Handshakes (TLS, then ndr's Hello) not done within the
    pre-authentication budget (3 s) or their own timeout."""
    failed_other: int
    refused_role: int
    refused_layout: int
    refused_settings: int
    refused_wire_version: int
    refused_protocol: int
    refused_transport: int
    """The peer runs another transport (one side over a stream, the other
    over datagrams)."""
    evicted: int
    """Pending handshakes cut short to make room for a new connection,
    every handshake slot being taken (the peer gets Close 15)."""
    refused_per_source: int
    """Pending handshakes cut short to make room for a newer connection
    from the same source, which had the most pending handshakes one source
    may have (8): one that had said least for longest goes (the peer gets
    Close 14). Over QUIC: the newer connection is closed at once instead."""
    refused_busy: int
    """Peers refused as busy after their handshake: the listener served as
    many links as it may, or (a shared robot) another base holds control."""
    refused_observer_only: int
    """A shared robot: bases that asked for control with an identity the
    TLS observers' allow-list names only (``TlsConfig(observer_pins=…)``)."""
    refused_observers_full: int
    """A shared robot: bases that asked to observe (or to wait for control)
    while every observer's seat was taken."""
    unclaimed: int
    """Links whose handshake was done but that the application did not
    take (the accept queue was full, or the link ended while it waited)."""
    accept_errors: int
    """Times the kernel could not hand over a connection (out of file
    descriptors or memory)."""
    datagrams_stray: int
    """Datagram transport: datagrams to the listener's UDP port with no
    token of a link it accepted (strays, spoofs, cut short), dropped."""
    retried: int
    """QUIC: new connections asked to prove their address first (a
    stateless Retry) because half the handshake slots or more were
    taken; a spoofed source never answers and takes no slot."""


class FloorStats(TypedDict):
    """The counters of a shared robot's floor (who holds control)."""

    handovers: int
    """Terms granted after the first: control changing hands."""
    observers_max: int
    """The most observers served at once."""
    refused_busy: int
    """Bases refused control because another held it."""
    refused_observer_only: int
    """Bases refused control because their identity may only observe."""
    refused_full: int
    """Bases refused because every observer's seat was taken."""
    actions_dropped: int
    """Decisions the listener did not carry out in time, given up."""


class SharingStats(TypedDict):
    """What a shared robot's listener counted (:attr:`Listener.sharing`)."""

    floor: FloorStats
    notes_dropped: int
    """Notes from the links to the floor it had no room for (applied
    commands not told to the observers, mostly)."""
    applied_forwarded: int
    """Applied commands told to observers."""


class LinkStats(TypedDict):
    """A snapshot of a link (:attr:`Link.stats`); times are seconds."""

    phase: str
    """Where the protocol is: ``"handshake"``, ``"init"``, ``"running"``,
    ``"pausing"`` or ``"closed"``."""
    period: float
    ns: int
    """The regulator's nominal size."""
    queue_len: int
    """Samples in the regulator now."""
    queue_range: Optional[Tuple[int, int]]
    """Occupancy before a release in the current regime, (min, max)."""
    last_nrtt: Optional[float]
    app_dropped: int
    """Releases and events dropped because the application did not read them."""
    events_dropped: int
    """Events dropped, the oldest first, because more than the link keeps
    waited unread (see :meth:`Link.events`)."""
    frames_sent: int
    frames_received: int
    samples_sent: int
    samples_repeated: int
    """Ticks that sent the previous sample again (none was given)."""
    samples_received: int
    released_fresh: int
    released_held: int
    underflows: int
    late: int
    rejected: int
    discarded: int
    skipped: int
    pauses: int
    resizes: int
    link_lost: int
    tx_dropped: int
    frames_missing: int
    """Data frames the peer numbered but never sent (its driver stalled
    past its transmit queue: its ``tx_dropped``), seen here as a gap."""
    outage_delays: int
    """Adaptive playout: frames after a silence longer than the watchdog
    (and the burst held behind them, or handed over by a driver that
    stalled) left out of its delay window."""
    clamped: int
    grtt_unmeasured: int
    probes_received: int
    probe_arrivals_dropped: int
    """Probe arrivals kept for a recording that it did not take in time."""
    datagrams_received: int
    """Datagram transport: datagrams of this session taken."""
    samples_recovered: int
    """Datagram transport: samples taken from a later datagram's copy."""
    samples_from_repeats: int
    """Datagram transport: samples taken from a repeat of their datagram
    (its first send lost)."""
    loss_reports: int
    """Datagram transport: times the peer reported more of this side's
    samples missed, each keeping this side's repeats going for 10 s."""
    samples_lost: int
    """Datagram transport: samples never received before a newer one."""
    datagrams_stale: int
    """Datagram transport: datagrams after a newer one (repeated,
    reordered, replayed; the peer's own repeats of a sample taken), dropped."""
    datagrams_repeated: int
    """Datagram transport: repeats sent (a sample's datagram again, 1 ms
    apart), while the peer reports losses."""
    datagrams_foreign: int
    """Datagram transport: datagrams of another session, dropped."""
    datagrams_refused: int
    """Datagram transport: datagrams refused for anything else, dropped."""
    datagrams_off_path: int
    """Datagram transport: valid datagrams from an address not validated as
    the peer's (a peer that moved, before it is validated; a stranger who
    saw a token), dropped."""
    tokens_renewed: int
    """Datagram transport: new tokens given to the peer to validate the
    address of a datagram from elsewhere."""
    paths_validated: int
    """Datagram transport: new tokens that came back in a datagram,
    validating the address it came from as the peer's."""
    nrtt: RunningStats
    """The network round trip."""
    grtt: RunningStats
    """The round trip the controller sees."""
    one_way_rx: RunningStats
    """One-way delay of what this side receives (from the clock estimate)."""
    one_way_tx: RunningStats
    """One-way delay of what this side sends."""
    clock_offset: float
    """The peer's clock offset from this side's."""
    clock_skew_ppm: float
    playout_delay: float
    """The delay a target-delay playout holds now (0 for the FIFO)."""
    playout_delay_ticks: int
    delay_changes: int
    round_trip_ticks: int
    """The round trip of this side's samples in periods, ``ceil(GRTT / T)``,
    the last measured (0 before the first)."""
    round_trip_changes: int
    """Changes of ``round_trip_ticks``, the first included (each one a
    ``"round_trip_changed"`` event)."""
    rx_lag: RunningStats
    """From a frame's arrival (the kernel's stamp) to its endpoint."""
    lateness: LatenessStats
    """How late the hub's thread woke for its deadlines."""
    release_lateness: LatenessStats
    """How late each release was stamped."""
    spin_margin: float
    """How long before a deadline the hub spins, learned from its timer."""
    role: str
    """``"controller"`` or ``"observer"``: whether this link observes now
    (:attr:`Link.is_observer`); a link of an unshared robot controls."""
    commands_refused_stale_term: int
    """Remote: commands of a control term this link no longer holds, never
    handed to the application (fencing after a hand-over)."""
    commands_refused_observer: int
    """Remote: commands from a base that holds no control, refused."""
    commands_before_grant: int
    """Remote: commands of a base given control that came before the grant,
    refused."""
    grants: int
    """Terms of control granted on this link."""
    applied_sent: int
    """Remote: applied commands sent to this link's observer."""
    applied_dropped: int
    """Remote: applied commands this link's observer was too slow for,
    dropped (the oldest first)."""
    applied_received: int
    """Base (an observer): applied commands received."""
    endpoint_events_dropped: int
    """Events the endpoint itself dropped (none from the hub, which takes
    the events of a long catch-up as the endpoint's queue fills)."""
    datagram_peer: Optional[str]
    """Datagram transport: where this side sends its datagrams (``"host:port"``,
    the peer's newest address); ``None`` on TCP, and on a listener's side
    until the peer's first datagram."""
    datagrams_unsent: int
    """Datagram transport: datagrams not sent (no address for the peer yet,
    or the socket refused them)."""
    datagram_path_changes: int
    """Datagram transport: times the peer's address changed."""
    datagrams_stray: int
    """Datagram transport: datagrams to this link's UDP socket with no
    token of a link on it (shared by the links on the socket), dropped."""
    zenoh_dropped: int
    """Zenoh transport: frames that reached the link while its inbox was
    full (its hub behind by hundreds of frames), dropped; 0 on the others."""
    waited: float
    """Seconds connecting waited for the remote (``connect_timeout``): from
    the first attempt to the one that reached it; 0 if it was there."""
    reconnects: int
    """``reconnect=True``: times the link lost its peer and came back (a
    new session passed its initialization pattern). The other counters are
    the current session's."""
    outage_total: float
    """``reconnect=True``: seconds the link was down in all, from each loss
    to the new session's start."""
    last_outage: Optional[float]
    """``reconnect=True``: the latest outage in seconds, once one ended."""
    longest_outage: float
    """``reconnect=True``: the longest outage in seconds."""
    stale: int
    """``reconnect=True``: releases refused because they belonged to a
    session that was over, or did not come after the last release given
    (0 unless something went wrong)."""


def _settings(args: Dict[str, Any]) -> "_native._LinkSettings":
    """The link settings among a call's arguments, checked once in Rust."""
    return _native._LinkSettings(
        **{native: args[name] for name, native in _SETTINGS.items() if name in args}
    )


def _check_timeout(timeout: Optional[float]) -> None:
    # The native receive's own check, for the asynchronous one that slices it.
    if timeout is not None and not 0.0 <= timeout < 1e9:
        raise ValueError(
            f"timeout must be None (wait forever) or a finite number of seconds ≥ 0, got {timeout}"
        )


def _is_normal_end(exc: BaseException) -> bool:
    if isinstance(exc, LinkClosedError):
        return True
    return isinstance(exc, PeerClosedError) and getattr(exc, "reason", None) == 0


class Link:
    """One side of a regulated link. Make one with :meth:`connect` or
    :meth:`Listener.accept`; use it as a context manager (or call
    :meth:`close`)."""

    def __init__(
        self,
        native: "_native._Link",
        *,
        on_event: Optional[Callable[[Event], Any]] = None,
    ) -> None:
        self._native = native
        self._on_event = on_event
        self._closed = False
        # A receive raised a LinkError: the link is over (for repr).
        self._ended = False
        self._executor: Optional[ThreadPoolExecutor] = None
        self._executor_lock = threading.Lock()
        self._pump()

    # -- making links -----------------------------------------------------

    @classmethod
    def connect(
        cls,
        address: Address,
        *,
        role: str = "base",
        axes: Optional[int] = None,
        command_width: Optional[int] = None,
        state_width: Optional[int] = None,
        period: float = 0.05,
        regulation: Optional[str] = None,
        underflow: str = "hold",
        watchdog: Optional[float] = 1.0,
        liveness: Optional[float] = 10.0,
        handshake_timeout: float = 10.0,
        connect_timeout: Optional[float] = 10.0,
        reconnect: bool = False,
        queue: int = 1024,
        tls: Optional[TlsConfig] = None,
        insecure: bool = False,
        transport: str = "tcp",
        realtime: str = "try",
        rt_priority: int = 49,
        rt_cpu: Optional[int] = None,
        observe: bool = False,
        wait_for_control: Optional[float] = None,
        on_event: Optional[Callable[[Event], Any]] = None,
        record: Optional[Union[str, "os.PathLike[str]"]] = None,
    ) -> "Link":
        """Connects to a peer and returns the link once the handshake is done.

        Args:
            address: ``"host:port"`` or ``(host, port)``.
            role: ``"base"`` (the operator's side, the default) or
                ``"remote"`` (a robot that dials out).
            axes: values per sample each way, 1 to 256 (a command and a state
                value per axis; 1 when no width is given); both peers must
                agree.
            command_width: values in each command (base → remote), 1 to
                256, when it differs from ``axes``: a 7-joint arm whose state
                is positions, velocities and torques has
                ``command_width=7, state_width=21``. Both peers must agree.
            state_width: values in each state (remote → base), 1 to 256.
            period: the sampling period in seconds; both peers must agree.
            regulation: how this side regulates the delay (the names of
                ``ndr demo --regulation`` and :data:`ndr.sim.REGULATIONS`):
                ``"adaptive[:PERCENT[:QUANTUM_MS]]"`` (the default: a
                target delay above the sample's send time, lower than the
                paper's FIFO at the same late rate; ``"adaptive"`` holds the
                smallest constant delay with a late rate of 0.1 %, or
                ``PERCENT``, in steps of the period up to 20 ms and of 1 ms
                at longer periods (within a 20 ms dead band), or
                ``QUANTUM_MS``: a finer step holds a lower delay that
                changes more often; a stall of the network is held, its
                samples released in order, not dropped, while that costs
                less delay per sample kept than a higher constant delay
                (once half that late rate is used), and always once it is
                spent; see docs/algorithms.md §9–10), ``"paper-static"``
                (the paper's FIFO, sized once by the initialization
                pattern), ``"paper-dynamic"`` (the FIFO resized, after a
                pause, as the network changes; both peers must say it),
                ``"ramjee-1"``, ``"ramjee-4"``, ``"neteq"``,
                ``"fixed[:MS]"`` or ``"constant:MS"``.
            underflow: what a tick does when its sample has not arrived:
                ``"hold"`` (the paper's FIFO: repeat the last sample, keep
                every sample) or ``"drop-late"`` (keep the delay constant:
                a late sample is dropped and counted).
            watchdog: seconds without a fresh sample before a
                ``"link_lost"`` event (hold the robot safely then); ``None``
                disables it. Under ``regulation="adaptive"`` a silence longer
                than this is an outage, not a delay to cover: its frames
                stay out of the delay's estimate (``stats["outage_delays"]``).
            liveness: seconds without anything from the peer, after the
                handshake, before the link ends (a hung peer, a half-open
                connection: receiving raises :class:`DisconnectedError`),
                so that a listener can serve the next peer; ``None`` waits
                for ever.
            handshake_timeout: seconds the handshake and each
                initialization pattern may take, at least: a pattern (and a
                pause of the dynamic mode) gets three times what it needs
                when that is longer (its probes at the period plus the
                slowest round trip seen).
            connect_timeout: seconds to wait for the remote: a remote not
                there yet (the connection refused, the host unreachable, no
                answer) is tried again, 0.1 s, 0.2 s, … up to 1 s apart,
                until it is reached or this time is over
                (``stats["waited"]`` says how long it took). ``None`` or 0:
                one attempt (``None``: within the operating system's limit).
            reconnect: a base whose link loses its peer (the connection
                dropped or reset, a restarted remote, the peer silent past
                ``liveness``, a remote that ended the link in order)
                connects again by itself, until it is back or the link is
                closed: receiving waits meanwhile (the robot holds on its
                watchdog), ``"link_lost"`` then ``"link_restored"`` (with
                the ``outage``) are raised, the new session runs its
                initialization pattern and announces its round trip
                (``"round_trip_changed"``), and the sequence numbers of
                its releases carry on after the last one given: nothing of
                the old session comes after them. A peer that refuses the
                link (other settings, a certificate) ends it as without
                this. ``stats`` counts ``reconnects`` and
                ``outage_total``.
            queue: released samples and events that may wait for the
                application (1 to 2**20); beyond it the newest are dropped
                and counted (``stats["app_dropped"]``).
            tls: a :class:`TlsConfig`: mutual TLS 1.3, both sides present
                certificates (``ndr keygen`` makes a pair). Without it a link
                to or from a non-loopback address is refused…
            insecure: …unless this is true (plain TCP: anyone on the path
                can read and forge the samples). Loopback is always allowed.
            transport: how samples cross: ``"tcp"`` (the paper's stream,
                where a lost packet holds back every sample behind it until
                it is resent) or ``"udp"`` / ``"udp:K"`` / ``"udp:K:R"``
                (datagrams, each carrying the newest sample and copies of
                the K − 1 before it, 4 by default, sent R more times 1 ms
                apart, 3 by default, while the peer reports losses, so that
                a lost one is made good within a millisecond or two; the
                handshake stays on TCP and the
                datagrams use the same port over UDP). UDP is plain:
                loopback, or ``insecure=True``, and not with ``tls``.
                ``"quic"`` / ``"quic:K"`` / ``"quic:K:R"``: the same
                datagrams as QUIC DATAGRAM frames, the handshake on a QUIC
                stream, all under mutual TLS 1.3 (``tls`` is then required
                on both sides; one UDP port, no TCP). Both sides must agree.
            realtime: real-time scheduling of the link's hub thread (the
                thread that keeps the release clock): ``"try"`` (the
                default: ``SCHED_FIFO`` at ``rt_priority`` and locked memory
                where the host grants them, which takes a loaded machine's
                scheduler out of the release times; else one warning, logged
                through ``logging``, saying what to grant, and the default
                policy), ``"enforce"`` (refuse to run without them:
                ``PermissionError``) or ``"off"``. Granted to root, or by
                ``setcap cap_sys_nice,cap_ipc_lock+ep`` on the Python
                binary, or by rtprio and memlock limits
                (docs/guide/realtime.md).
            rt_priority: the hub thread's ``SCHED_FIFO`` priority, 1 to 99.
            rt_cpu: pin the hub thread to this CPU (``None``: any).
            observe: a base that watches a shared robot
                (``Link.listen(observers=N)``): it receives the states, at
                its own constant delay, and the commands the robot applied
                (``"applied"`` events), and sends none (what it sends is
                not applied). A robot that shares nothing refuses it.
            wait_for_control: a base that asks for control and, while
                another base holds it, observes until control frees (the
                controller closes, yields or is dropped by the liveness
                rule) and is granted it: a ``"control_granted"`` event, then
                its commands apply. Seconds it waits at most: past them
                without a grant, the link is closed and receiving raises
                :class:`LinkError` saying so. Not with ``observe``.
            on_event: called with each :class:`Event`, on the thread that
                receives.
            record: an MCAP file to record the link to (created, or
                replaced): every release with its send and release times,
                the link's events, its counters once a second and each
                arrival's one-way delay, written by a thread of its own;
                finished when the link closes. Read it with
                :func:`ndr.read_recording`, plot it with ``python -m ndr
                plot``, open it in Foxglove, replay it with ``ndr sim
                --trace``.

        Raises:
            ConnectionRefusedError: nothing listens at ``address``.
            HandshakeError: the peer has other settings, or did not answer.
            TimeoutError: no connection within ``connect_timeout`` (a
                remote that never answered).
            ConnectionRefusedError: still refused when ``connect_timeout``
                was over (nothing listens at ``address``).
            ValueError: a setting is invalid (the message says which), a
                plain link off loopback without ``insecure=True``, or
                ``observe=True`` with ``wait_for_control``.
            PeerClosedError: the robot refused the seat asked for: control
                held by another base (``reason_name`` ``"busy"``; connect
                with ``wait_for_control``), every observer's seat taken, or
                an identity that may only observe asking for control.
            PermissionError: ``realtime="enforce"`` and the host refused
                real-time scheduling (the message says what to grant).
        """
        native = _native.connect(
            address,
            _settings(locals()),
            connect_timeout=connect_timeout,
            reconnect=reconnect,
            tls=tls,
            record=None if record is None else os.fspath(record),
        )
        return cls(native, on_event=on_event)

    @classmethod
    def listen(
        cls,
        address: Address,
        *,
        role: str = "remote",
        axes: Optional[int] = None,
        command_width: Optional[int] = None,
        state_width: Optional[int] = None,
        period: float = 0.05,
        regulation: Optional[str] = None,
        underflow: str = "hold",
        watchdog: Optional[float] = 1.0,
        liveness: Optional[float] = 10.0,
        handshake_timeout: float = 10.0,
        queue: int = 1024,
        tls: Optional[TlsConfig] = None,
        insecure: bool = False,
        transport: str = "tcp",
        realtime: str = "try",
        rt_priority: int = 49,
        rt_cpu: Optional[int] = None,
        observers: Optional[int] = None,
        on_event: Optional[Callable[[Event], Any]] = None,
        record: Optional[Union[str, "os.PathLike[str]"]] = None,
    ) -> "Listener":
        """Listens at ``address`` (port 0 picks a free one) and returns a
        :class:`Listener` whose :meth:`~Listener.accept` gives one link per
        peer. The keyword arguments are those of :meth:`connect`; ``role``
        defaults to ``"remote"``; with ``record``, every link it accepts is
        recorded into that one file, finished when the listener and its
        links are closed.

        ``observers=N`` (0 to 64; ``ndr remote`` shares with 4) shares one
        robot: one base controls, up to ``N`` observe (``observe=True``, and
        bases waiting for control), control changes hands safely (each term
        numbered; no command of an earlier term applies after a hand-over;
        between terms the robot gets no command and holds). The application
        accepts every link, sends its state on each, and applies what any of
        them releases (only the controller's commands are released; each
        :class:`Tick` carries its ``term``). ``None`` (the default): every
        link is its own, each base commanding on its own link (a server of
        many robots)."""
        native = _native.listen(
            address,
            _settings(locals()),
            tls=tls,
            record=None if record is None else os.fspath(record),
        )
        return Listener(native, on_event=on_event)

    # -- sharing ----------------------------------------------------------

    def yield_control(self) -> None:
        """A base that holds control on a shared robot gives it up: the link
        goes on as an observer's, and the robot hands control to a base
        waiting for it (its ``"control_granted"``). A ``"control_lost"``
        event follows here; a base that holds no control gets none.

        Raises:
            ValueError: on the remote's side.
            LinkError: the link has ended.
        """
        self._native.yield_control()

    @property
    def is_observer(self) -> bool:
        """Whether this link observes now: a base without control (it asked
        to observe, waits for control, or lost or yielded it), or a
        remote's link to such a base. ``stats["role"]`` says the same as
        ``"observer"`` or ``"controller"``."""
        return self._native.is_observer

    @property
    def peer_seat(self) -> Optional[str]:
        """The seat the peer's Hello named: at the remote, the one its base
        asked for (``"control"``, ``"observe"``, ``"wait_for_control"``);
        at the base, the one the robot gave (``"observe"`` to a base
        waiting for control). Later changes come as events."""
        return self._native.peer_seat

    # -- samples ----------------------------------------------------------

    def send(self, sample: SampleLike) -> None:
        """Sets the sample sent at the next tick: a float64 array (or any
        sequence of numbers) of shape ``(axes,)``; a plain number when
        ``axes`` is 1. At a tick where none was given, the previous one is
        sent again (and counted in ``stats["samples_repeated"]``).

        Raises:
            ValueError: wrong shape, dtype, or a NaN/infinite value.
            LinkError: the link has ended (the subclass says how).
        """
        self._native.send(sample)

    def recv(self, timeout: Optional[float] = None) -> Tick:
        """The next released sample, waiting at most ``timeout`` seconds
        (``None``: as long as it takes).

        Raises:
            TimeoutError: no sample within ``timeout`` (the link is still up).
            LinkError: the link has ended; ``PeerClosedError`` with
                ``reason == 0`` or ``LinkClosedError`` for a normal end.
        """
        try:
            tick = self._native.recv(timeout)
        except BaseException:
            self._ended_by_error()
            raise
        return self._delivered(tick)

    def try_recv(self) -> Optional[Tick]:
        """The next released sample if one is waiting, else ``None``."""
        try:
            tick = self._native.try_recv()
        except BaseException:
            self._ended_by_error()
            raise
        if tick is None:
            if self._native.unseen_events:
                self._pump()
            return None
        return self._delivered(tick)

    def _ended_by_error(self) -> None:
        """A receive raised: the events that say why go out first."""
        exc = sys.exc_info()[1]
        if isinstance(exc, _native.LinkError):
            self._ended = True
        if self._native.unseen_events:
            self._pump()

    def _delivered(self, tick: Tick) -> Tick:
        """Events, then the tick. If an ``on_event`` callback raises, the
        tick goes back in front of the queue (the next receive returns it)
        and the callback's exception propagates: nothing is lost."""
        try:
            if self._native.unseen_events:
                self._pump()
        except BaseException:
            self._native.unrecv(tick)
            raise
        return tick

    def ticks(self, timeout: Optional[float] = None) -> Iterator[Tick]:
        """Iterates over released samples, one per period, until the link
        ends normally (the peer closed it, or :meth:`close` was called).
        ``timeout`` bounds the wait for each tick (``TimeoutError``). A link
        that fails raises its :class:`LinkError` subclass."""
        while True:
            try:
                tick = self.recv(timeout)
            except (PeerClosedError, LinkClosedError) as e:
                if _is_normal_end(e):
                    return
                raise
            yield tick

    def __iter__(self) -> Iterator[Tick]:
        return self.ticks()

    # -- asyncio ----------------------------------------------------------

    async def arecv(self, timeout: Optional[float] = None) -> Tick:
        """:meth:`recv` for asyncio: waits on a worker thread of the link,
        without blocking the event loop. Cancelling it loses nothing: a
        sample it had already taken is put back for the next receive."""
        _check_timeout(timeout)
        if self._closed:
            raise LinkClosedError("the link is closed")
        call = _AsyncRecv(self, timeout)
        loop = asyncio.get_running_loop()
        future = loop.run_in_executor(self._worker(), call.run)
        try:
            tick = await future
        except asyncio.CancelledError:
            call.cancel()
            raise
        if tick is None:
            # Cancelled by close() from another thread while it waited.
            raise LinkClosedError("the link is closed")
        return self._delivered(tick)

    async def aticks(self, timeout: Optional[float] = None) -> AsyncIterator[Tick]:
        """:meth:`ticks` for asyncio: ``async for tick in link.aticks():``."""
        while True:
            try:
                tick = await self.arecv(timeout)
            except (PeerClosedError, LinkClosedError) as e:
                if _is_normal_end(e):
                    return
                raise
            yield tick

    def _worker(self) -> ThreadPoolExecutor:
        with self._executor_lock:
            if self._executor is None:
                # One thread: asynchronous receives happen in order.
                self._executor = ThreadPoolExecutor(
                    max_workers=1, thread_name_prefix="ndr-arecv"
                )
            return self._executor

    # -- state ------------------------------------------------------------

    def events(self) -> List[Event]:
        """The :class:`Event` s since the last call, oldest first (each has
        gone to ``on_event`` and the log before). They wait in the native
        link, the one bound on them: the latest 256 (ndr-net's
        ``EVENT_BACKLOG``); older ones are dropped and counted in
        :attr:`events_dropped` and ``stats["events_dropped"]``."""
        self._pump()
        return [_event(kind, fields) for kind, fields in self._native.events()]

    @property
    def events_dropped(self) -> int:
        """Events dropped because :meth:`events` was not called for a long
        time (more than 256 waited): ``stats["events_dropped"]``, also
        before the first tick."""
        return self._native.events_dropped

    @property
    def stats(self) -> Optional[LinkStats]:
        """A snapshot of the link's state and counters (:class:`LinkStats`),
        ``None`` before its first tick. Times are seconds. Keys include ``phase``, ``period``,
        ``ns``, ``queue_len``, ``queue_range``, ``last_nrtt``, the counters
        (``samples_sent``, ``samples_received``, ``released_fresh``,
        ``released_held``, ``underflows``, ``late``, ``pauses``, …),
        ``nrtt`` and ``grtt`` (count, mean, std, min, max), ``lateness`` of
        the hub's wake-ups for its deadlines and ``release_lateness`` of
        the releases themselves (min, p50, p99, p999, max, mean; over all
        links of the hub), ``spin_margin`` (how long before a deadline the
        hub stops sleeping and spins, learned from how late its timer
        wakes), ``app_dropped`` and ``events_dropped``. The dict is the Rust
        ``LinkStats`` serialized (the endpoint's counters beside the
        link's): its keys are the Rust fields' serde names."""
        return self._native.stats()

    def metrics(self) -> str:
        """The link's figures as Prometheus text (version 0.0.4): the page
        ``ndr remote --metrics`` serves, for this link alone, labelled with
        ``peer``, ``role`` and ``transport``. The same numbers as
        :attr:`stats` (read from the same snapshot of the hub), under the
        names listed in ``docs/guide/metrics.md``. An application with a
        ``prometheus_client`` registry registers :class:`ndr.metrics.LinkCollector`
        instead; one that exports otherwise parses this text (e.g.
        ``prometheus_client.parser.text_string_to_metric_families``)."""
        return self._native.metrics()

    def now(self) -> float:
        """Now, in seconds on this side's link clock (the clock of
        ``Tick.released_at`` and ``Tick.arrived_at``)."""
        return self._native.now()

    @property
    def recording(self) -> Optional[Dict[str, int]]:
        """The recording's counts (``record=``): ``links`` attached,
        events ``queued`` for its writer and ``dropped`` (its queue was
        full: the writer fell behind), MCAP messages ``written`` and
        ``chunks`` written out; ``None`` without a recording or once the
        link is closed."""
        return self._native.recording()

    @property
    def axes(self) -> int:
        """Values per sample when commands and states have the same width;
        ``AttributeError`` otherwise (read :attr:`command_width` and
        :attr:`state_width`)."""
        return self._native.axes

    @property
    def command_width(self) -> int:
        """Values in each command (base → remote)."""
        return self._native.command_width

    @property
    def state_width(self) -> int:
        """Values in each state (remote → base)."""
        return self._native.state_width

    @property
    def width(self) -> int:
        """Values in each sample this side sends: :attr:`command_width` at
        the base, :attr:`state_width` at the remote."""
        return self.command_width if self.role == "base" else self.state_width

    @property
    def period(self) -> float:
        """The period the link was set up with, in seconds (dynamic mode
        may change it: see ``stats["period"]``)."""
        return self._native.period

    @property
    def role(self) -> str:
        """``"base"`` or ``"remote"``."""
        return self._native.role

    @property
    def peer(self) -> Tuple[str, int]:
        """The peer's address, ``(host, port)``."""
        return self._native.peer

    @property
    def closed(self) -> bool:
        """Whether :meth:`close` was called."""
        return self._closed

    def close(self) -> None:
        """Closes the link, a normal end: the peer is told (a Close frame),
        a ``"closed"`` event follows here, and receiving then raises
        ``LinkClosedError``. Idempotent."""
        self._end(self._native.close)

    def abort(self) -> None:
        """Ends the link as a failure of this program: the peer is told
        "application failure" (Close code 8), so its receive raises
        ``PeerClosedError`` (``reason == 8``) instead of ending normally,
        and a robot holds safely rather than taking it for a deliberate
        stop. An exception leaving a ``with`` block does this, and so does a
        link garbage-collected without :meth:`close`. Idempotent; a no-op
        after :meth:`close`."""
        self._end(self._native.abort)

    def _end(self, how: Callable[[], None]) -> None:
        if self._closed:
            return
        self._closed = True
        how()
        try:
            self._pump()
        finally:
            if self._executor is not None:
                self._executor.shutdown(wait=False)

    def __enter__(self) -> "Link":
        return self

    def __exit__(self, exc_type: Optional[type], *rest: object) -> None:
        # An exception (Ctrl-C included) is not a deliberate end.
        if exc_type is None:
            self.close()
        else:
            self.abort()

    def __repr__(self) -> str:
        host, port = self.peer
        state = "closed" if self._closed else "ended" if self._ended else "open"
        return (
            f"<ndr.Link {self.role} peer={host}:{port} widths={self.command_width}×{self.state_width} "
            f"period={self.period:g}s {state}>"
        )

    # -- events -----------------------------------------------------------

    def _pump(self) -> None:
        # The events not seen yet go to the log and ``on_event`` (they stay
        # in the native link for :meth:`events`), every one even if the
        # callback raises for one; its first exception then propagates.
        failure: Optional[BaseException] = None
        for kind, fields in self._native.new_events():
            event = _event(kind, fields)
            _log_event(self, event)
            if self._on_event is None:
                continue
            try:
                self._on_event(event)
            except BaseException as e:  # noqa: BLE001 - re-raised below
                if failure is None:
                    failure = e
        if failure is not None:
            raise failure


def _event(kind: str, fields: Dict[str, Any]) -> Event:
    # An applied command's values are the event's own field (an array in
    # ``details`` would make events uncomparable).
    values = fields.pop("values", None)
    return Event(
        kind,
        period=fields.get("period"),
        ns=fields.get("ns"),
        silent_for=fields.get("silent_for"),
        outage=fields.get("outage"),
        delay=fields.get("delay"),
        ticks=fields.get("ticks"),
        grtt=fields.get("grtt"),
        error=fields.get("error"),
        term=fields.get("term"),
        values=values,
        details=fields,
    )


def _log_event(link: Link, e: Event) -> None:
    who = link.role
    if e.kind == "link_lost":
        _log.warning("%s: link lost: no fresh sample for %.3f s", who, e.silent_for or 0.0)
    elif e.kind == "closed" and not e.details.get("normal", True):
        _log.warning("%s: link closed: %s", who, e.error)
    elif e.kind == "delay_changed":
        _log.info("%s: delay now %.6g s (%s periods)", who, e.delay, e.ticks)
    elif e.kind == "round_trip_changed":
        _log.debug("%s: round trip now %s periods (GRTT %.6g s)", who, e.ticks, e.grtt)
    elif e.kind == "applied":
        _log.debug("%s: applied a command of term %s", who, e.term)
    elif e.kind in ("control_granted", "control_lost", "control_yielded"):
        _log.info("%s: %s, term %s", who, e.kind.replace("_", " "), e.term)
    elif e.kind in ("started", "paused"):
        _log.info("%s: %s, period %.6g s, ns %s", who, e.kind, e.period, e.ns)
    else:
        _log.info("%s: %s", who, e.kind)


class _AsyncRecv:
    """One asynchronous receive: waits in slices on the link's worker thread,
    and gives back a tick that arrives after it was cancelled."""

    def __init__(self, link: Link, timeout: Optional[float]) -> None:
        self._link = link
        self._timeout = timeout
        self._lock = threading.Lock()
        self._cancelled = False
        self._taken: Optional[Tick] = None

    def run(self) -> Optional[Tick]:
        native = self._link._native
        waited = 0.0
        while True:
            with self._lock:
                if self._cancelled:
                    return None
            slice_ = _ASYNC_SLICE
            if self._timeout is not None:
                slice_ = min(slice_, max(self._timeout - waited, 0.0))
            try:
                tick = native.recv(slice_)
            except TimeoutError:
                waited += slice_
                if self._timeout is not None and waited >= self._timeout:
                    raise TimeoutError(
                        f"no sample within {self._timeout} s (the link is still up)"
                    ) from None
                continue
            except BaseException:
                self._link._ended_by_error()
                raise
            with self._lock:
                if self._cancelled:
                    native.unrecv(tick)
                    return None
                self._taken = tick
            return tick

    def cancel(self) -> None:
        with self._lock:
            self._cancelled = True
            if self._taken is not None:
                self._link._native.unrecv(self._taken)
                self._taken = None


class Listener:
    """Accepts links, one per peer (from :meth:`Link.listen`). A peer whose
    handshake fails is logged, counted in :attr:`refused` and skipped; the
    listener keeps serving.

    The handshakes run while :meth:`accept` (or iteration) waits: a peer
    that connects in between waits for it, so a program that both listens
    and connects must accept on another thread than the one that connects
    (a ``connect`` made before anyone accepts times out)."""

    def __init__(
        self,
        native: "_native._Listener",
        *,
        on_event: Optional[Callable[[Event], Any]] = None,
    ) -> None:
        self._native = native
        self._on_event = on_event

    def accept(self, timeout: Optional[float] = None) -> Link:
        """The next peer whose handshake succeeds, as a running :class:`Link`.

        Raises:
            TimeoutError: no such peer within ``timeout`` seconds.
            LinkClosedError: the listener was closed.
        """
        native = self._native.accept(timeout)
        if native is None:
            raise TimeoutError(f"no peer completed a handshake within {timeout} s")
        return Link(native, on_event=self._on_event)

    def __iter__(self) -> Iterator[Link]:
        """Links, one per peer, for as long as the listener is open."""
        while True:
            try:
                yield self.accept()
            except LinkClosedError:
                return

    @property
    def address(self) -> Tuple[str, int]:
        """The address it listens on, ``(host, port)``."""
        return self._native.address

    @property
    def refused(self) -> int:
        """Peers refused: a failed TLS handshake (unknown or missing
        certificate, old TLS, timeout), a failed ndr handshake (other
        settings), or turned away by the listener (evicted, too many from
        one source, busy, never taken, an observer's identity asking for
        control, every observer's seat taken)."""
        return self._native.refused

    @property
    def stats(self) -> ListenerStats:
        """The listener's counters by reason (:class:`ListenerStats`):
        ``accepted``; TLS: ``refused_certificate``,
        ``refused_no_certificate``, ``refused_version``; ndr's handshake:
        ``refused_role``, ``refused_layout``, ``refused_settings`` (period,
        mode), ``refused_wire_version``, ``refused_protocol``,
        ``refused_transport``; ``timeouts``,
        ``failed_other``; and those the listener turned away before they
        authenticated or after: ``evicted``, ``refused_per_source``,
        ``refused_busy``, ``unclaimed``; ``accept_errors``; over QUIC,
        ``retried``. Connections are accepted and handshaken in the
        background, also while the application is busy with a link. A
        shared robot counts ``refused_observer_only`` and
        ``refused_observers_full`` too."""
        return self._native.stats

    @property
    def sharing(self) -> Optional[SharingStats]:
        """A listener that shares its robot (``observers=``): its
        :class:`SharingStats`, ``floor["handovers"]`` (control changing
        hands), ``floor["observers_max"]``, the refusals, and the applied
        commands told to observers; ``None`` otherwise."""
        return self._native.sharing

    def close(self) -> None:
        """Stops listening; links already accepted go on."""
        self._native.close()

    def __enter__(self) -> "Listener":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        host, port = self.address
        return f"<ndr.Listener {host}:{port}>"
