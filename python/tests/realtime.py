"""What every test of a real link's constant delay shares (as the Rust
tests' ``tests/common/mod.rs``): on a shared host, a hub can be held for a
millisecond or more, and past the queue's slack the FIFO's delay then
steps by a period, by design. Each test runs once and is judged with
margins the host cannot break: order strictly, completeness but for
counted drops, and the delay at its level with at most a tenth of strays
(each less its release's lateness, where the test has the release times),
the others within 1 ms std. That the regulation makes the delay exactly
constant is judged in simulated time (``test_sim.py``, ``test_demo.py``)."""

from typing import Any, Callable, Iterable, List, Mapping, Optional, Sequence, Tuple

import numpy as np

import ndr

# Delays in a row at one level that make it a level of the FIFO, not an
# excursion of the host.
SETTLED = 10


def host_stalls(stats: Iterable[Optional[Mapping[str, Any]]]) -> int:
    """Signs that the host, not the link, stalled: a hub that served a
    deadline or a release 1 ms late or more (a period, if shorter), or a
    frame that took that long across loopback (on an idle host, each is
    tens of µs)."""
    signs = 0
    for s in stats:
        if not s:
            continue
        bound = min(s["period"], 1e-3)
        for d in (
            s["lateness"]["max"],
            s["release_lateness"]["max"],
            s["nrtt"]["max"],
            s["one_way_rx"]["max"],
        ):
            signs += d >= bound
    return signs


class Stalls(int):
    """Signs that the host stalled a run (0: it did not), and ``missed``, the
    deadlines its hubs woke for 1 ms late or more (``lateness.missed``):
    each may put the two GRTTs around it off their level."""

    missed: int

    def __new__(cls, signs: int, missed: int = 0) -> "Stalls":
        stalls = super().__new__(cls, signs)
        stalls.missed = missed
        return stalls


def on_schedule(delays: np.ndarray, released_at: Sequence[float], period: float) -> np.ndarray:
    """Each delay less the lateness of the release that measured it: how
    far past the release grid (the median phase of the releases, which are
    on time but when the host holds the hub) it was released, up to nine
    tenths of a period (a hub never releases early; a tenth is left for the
    grid's own spread). What the host adds is the hub's lateness, which its
    own histogram reports; what is left is the link's."""
    phase = np.mod(np.asarray(released_at, dtype=float), period)

    def centred(p, origin):
        return np.mod(p - origin + period / 2, period) - period / 2

    grid = phase[0] + float(np.median(centred(phase, phase[0])))
    late = np.mod(phase - grid + period / 10, period) - period / 10
    return delays - np.maximum(late, 0.0)


def assert_constant(
    delays: Sequence[float],
    stalls: int,
    what: str = "delay",
    released_at: Optional[Sequence[float]] = None,
    period: Optional[float] = None,
    underflows: int = 0,
) -> None:
    """At most 1 ms std: that of the delays within 2 ms of the median, the
    others (at most a tenth) set aside, each delay less its release's
    lateness when ``released_at`` (the hub's clock, s) and the ``period``
    are given, and at its level: whole periods from the median, held for
    ``SETTLED`` delays in a row or more (a briefer excursion is strays), the
    level changing at most twice per counted underflow (``underflows``:
    past the queue's slack the FIFO's delay steps by a period, by design).
    The strays allowed are a tenth, and two for each tick a hub missed
    (``stalls.missed``, when ``stalls`` comes from :func:`regulated`)."""
    d = np.asarray(delays, dtype=float)
    assert d.size > 100, f"{d.size} {what}s"
    if released_at is not None and period is not None:
        d = on_schedule(d, released_at, period)
    # One of the delays, as the Rust judge takes it: the mean of the two
    # middle ones falls between two levels when half the delays sit on
    # each, and every delay is then off it by half a period.
    median = float(np.sort(d)[d.size // 2])
    brief = np.zeros(d.size, dtype=bool)
    if period is not None:
        level = np.round((d - median) / period)
        # Runs of one level; one held for fewer than SETTLED delays in a
        # row is the host's excursion (its delays strays), not a level.
        starts = np.flatnonzero(np.r_[True, np.diff(level) != 0])
        lengths = np.diff(np.r_[starts, d.size])
        brief = np.repeat(lengths < SETTLED, lengths)
        settled = level[starts][lengths >= SETTLED]
        steps = int(np.count_nonzero(np.diff(settled)))
        missed = getattr(stalls, "missed", 0)
        # Two sides' tick grids that meet within the host's jitter make a
        # frame count for one tick or the next: two adjacent levels, in turn.
        adjacent = settled.size == 0 or float(np.ptp(settled)) <= 1
        if float(np.ptp(level)) <= 1:
            # Only two adjacent levels in all: a flip, not an excursion.
            brief = np.zeros(d.size, dtype=bool)
        assert steps <= 2 * underflows + missed or adjacent, (
            f"the {what} changed level {steps} times, {underflows} underflows and {missed} "
            "ticks missed counted: "
            f"levels {list(zip(level[starts].tolist(), lengths.tolist()))}"
        )
        d = d - level * period
    off = brief | (np.abs(d - median) > 2e-3)
    strays = d[off]
    missed = getattr(stalls, "missed", 0)
    allowed = d.size // 10 + 2 * missed
    assert strays.size <= allowed, (
        f"{strays.size} {what}s in a brief excursion or more than 2 ms from the median "
        f"{median}, {allowed} allowed ({missed} ticks missed; host stalls: {int(stalls)}): "
        f"{strays}"
    )
    d = d[~off]
    # Every one set aside is within what the hubs' missed ticks allow.
    if d.size == 0:
        return
    assert float(np.std(d)) <= 1e-3, f"{what} std {np.std(d)} s (host stalls: {int(stalls)})"


def missing_but_counted(seqs: Sequence[int], counted: int) -> int:
    """The samples missing from ``seqs`` (a side's fresh releases), after
    checking that none was released twice or out of order and that no more
    are missing than the sides counted (the sender's ``tx_dropped``: a hub
    the host held past its transmit queue; the receiver's
    ``samples_lost``: datagrams the kernel dropped meanwhile)."""
    steps = np.diff(np.asarray(seqs, dtype=np.int64))
    assert (steps >= 1).all(), f"released twice or out of order: {seqs}"
    missing = int((steps - 1).sum())
    assert missing <= counted, f"{missing} missing, {counted} counted: {seqs}"
    return missing


def regulated(
    run: Callable[[], Tuple[Any, List[Optional[Mapping[str, Any]]]]],
    missing: Callable[[Any], int] = lambda _: 0,
) -> Tuple[Any, Stalls]:
    """Runs ``run`` once (it checks order and completeness itself and
    returns its result and the links' stats): the result, and the signs
    that the host stalled it, for what may be judged only on a run it did
    not stall (a side's counted drops, whose absence is also judged in
    simulated time). A run whose ``missing(result)`` is not zero (samples
    the host made a side drop, counted) is a stalled one."""
    result, stats = run()
    missed = sum(s["lateness"]["missed"] for s in stats if s)
    return result, Stalls(host_stalls(stats) + (missing(result) > 0), missed)


def counted_gaps(receiver: Optional[Mapping[str, Any]], sender: Optional[Mapping[str, Any]]) -> int:
    """The samples the counters account for, that the receiver's application
    never saw fresh: the sender's ``tx_dropped`` (a hub held past its
    transmit queue), and the receiver's ``samples_lost`` (datagrams),
    ``app_dropped`` (its application's queue full), ``rejected``,
    ``discarded`` and ``skipped``."""
    n = 0 if sender is None else int(sender["tx_dropped"])
    if receiver is not None:
        n += sum(int(receiver[k]) for k in
                 ("samples_lost", "app_dropped", "rejected", "discarded", "skipped"))
    return n


def assert_round_trips(grtts: Sequence[Optional[float]], accounted: int) -> None:
    """Each of the base's releases after the first that measured a round
    trip (``grtts``, ``None`` or NaN where none) measured one too, but at
    most ``accounted``, those a counter explains: an underflow on either
    side (the base's release held, or the remote's state then answering no
    newer command), the remote's ``samples_repeated`` (its application gave
    no new state in time: the one sent again answers an old command), a
    sample counted as never come. A host that holds a hub makes releases
    late, not fewer, and a late release still measures its round trip."""
    measured = [g is not None and not np.isnan(g) for g in grtts]
    first = measured.index(True) if True in measured else len(measured)
    without = measured[first:].count(False)
    assert without <= accounted, (
        f"{without} releases after the first round trip measured none, {accounted} accounted for"
    )


def no_gap(ticks: Sequence[Any], counted: int = 0) -> bool:
    """Each tick the next sample, or the last one held again (a late one,
    or the adaptive playout's rise): none twice fresh, none out of order,
    and none lost but ``counted`` (the samples a counter accounts for: the
    sender's ``tx_dropped``, a hub the host held past its transmit queue;
    a datagram receiver's ``samples_lost``)."""
    missing = 0
    for a, b in zip(ticks, ticks[1:]):
        if b.seq == a.seq + 1 or (b.seq == a.seq and b.status == "held"):
            continue
        if b.seq > a.seq + 1:
            missing += b.seq - a.seq - 1
            continue
        return False
    return missing <= counted


def echo(link: Any, stop: Any) -> None:
    """The remote's controller for these tests, on a thread of its own:
    sends back what each release gives, so that its answer has a whole
    period to reach the next tick (an answer from the base's loop would
    have only what separates the two sides' tick grids, which a busy host
    overruns now and then)."""
    try:
        while not stop.is_set():
            try:
                tick = link.recv(timeout=0.1)
            except TimeoutError:
                continue
            link.send(tick.sample)
    except ndr.LinkError:
        pass
