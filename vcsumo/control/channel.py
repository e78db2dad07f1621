"""Train-to-train communication channel: delay, loss and outages, seeded and reproducible.

Messages are sent at a fixed period (Terlizzi et al.: 1 s) and delivered after a random delay,
unless lost.  Delay models:

* ``constant`` — every message is delayed by ``delay_s``;
* ``exponential`` — ``delay_s`` + Exp(mean ``mean_extra_s``) (the seed paper's lossy channel);
* ``empirical`` — drawn from a list of measured delays ``samples_s``.

``loss_probability`` drops each message independently; ``outages`` are time windows in which
nothing is delivered; ``degradations`` are windows with their own (worse) delay/loss.  Messages
are delivered in send order per link (a late message never overtakes a newer delivered one).
The same seed gives the same deliveries.  Controllers only see what :meth:`Channel.deliver`
returns (plus on-board sensing).

:meth:`ChannelConfig.age_budget_s` is the age of the newest message a follower holds that the
channel keeps with probability :data:`AGE_QUANTILE` per sending period (from its period, delay
law and loss; outages and degradations are exceptions it does not budget): the age the nominal
controller's certified spacing budgets (:class:`vcsumo.control.gap_reference.SeparationGap`), so
that it does not track a spacing the CBF and the separation guard — which use the true age —
consider unsafe whenever a packet is a little late.
"""

from __future__ import annotations

import heapq
import math
from dataclasses import replace
from typing import Annotated, Literal

import numpy as np
from pydantic import Field

from vcsumo.config import StrictModel
from vcsumo.control.base import Message

AGE_QUANTILE = 0.99
"""Probability per sending period with which the channel keeps the newest message a follower holds
within :meth:`ChannelConfig.age_budget_s` [A]: the rest (1 %: at 2 Hz at most 72 excursions per
follower-hour) is left to the safety layers, which act on the true age."""

AGE_SEARCH_MAX_S = 600.0
"""Longest age budget searched, s (a channel that loses nearly everything: the budget is capped here)."""



class Window(StrictModel):
    """A time window [start_s, end_s)."""

    start_s: float
    end_s: float


class Degradation(Window):
    """A window with its own delay and loss."""

    delay_s: float = Field(default=0.0, ge=0, le=3600, description="Extra constant delay in the window, s (0–3,600)")
    mean_extra_s: float = Field(default=0.0, ge=0, le=3600, description="Mean of an extra exponential delay in the window, s (0–3,600)")
    loss_probability: float = Field(default=0.0, ge=0, le=1, description="Loss probability per message in the window, 0–1")
    exponential_mean_s: float | None = Field(default=None, ge=0, le=3600, description="Mean of the exponential delay in the window in place of the channel's mean_extra_s (an exponential channel whose rate changes, e.g. 15 → 3 /s), s (0–3,600)")


class ChannelConfig(StrictModel):
    """Channel settings (all times in s)."""

    model: Literal["ideal", "constant", "exponential", "empirical"] = "ideal"
    period_s: float = Field(default=1.0, ge=0.01, le=60, description="Sending period of each train, s (10 ms–60 s)")
    delay_s: float = Field(default=0.0, ge=0, le=3600, description="Constant (or minimum) delay, s (0–3,600; a message an hour late is lost)")
    mean_extra_s: float = Field(default=0.0, ge=0, le=3600, description="Mean of the exponential extra delay, s (0–3,600)")
    samples_s: list[Annotated[float, Field(ge=0, le=3600)]] = Field(default_factory=list, description="Empirical delay samples, s (each 0–3,600)")
    loss_probability: float = Field(default=0.0, ge=0, le=1, description="Independent loss probability per message, 0–1 (a probability)")
    outages: list[Window] = Field(default_factory=list, description="Windows without any delivery")
    degradations: list[Degradation] = Field(default_factory=list, description="Windows with worse delay/loss")
    seed: int = Field(default=0, ge=0, description="Seed of the channel's random numbers (numpy needs it not negative)")

    def age_budget_s(self, quantile: float = AGE_QUANTILE) -> float:
        """The message age this channel keeps with probability ``quantile`` per sending period, s
        (:func:`age_budget_s`)."""
        return age_budget_s(self, quantile)


def _delay_exceedance(cfg: ChannelConfig, x_s: float) -> float:
    """P(delay > x) of the channel's delay law (no degradation window), -."""
    if cfg.model == "ideal":
        return 1.0 if x_s < 0.0 else 0.0
    if cfg.model == "constant":
        return 1.0 if x_s < cfg.delay_s else 0.0
    if cfg.model == "exponential":
        if x_s < cfg.delay_s:
            return 1.0
        return math.exp(-(x_s - cfg.delay_s) / cfg.mean_extra_s) if cfg.mean_extra_s > 0 else 0.0
    return sum(1 for d in cfg.samples_s if d > x_s) / len(cfg.samples_s)


def age_exceedance(cfg: ChannelConfig, age_s: float) -> float:
    """Probability that the newest message a receiver holds grows older than ``age_s`` before a newer
    one arrives, counted from a message's send time: none of the messages sent after it, every
    ``period_s``, is delivered within ``age_s`` of it — Π_k [p + (1 − p)·P(D > age − k·P)] over
    k = 1 … ⌊age/P⌋ (each lost with p or later than its remaining time, independently), -.

    Each excursion of the age beyond ``age_s`` starts at the newest message then held, so the
    expected number of excursions per sending period is at most this value (outages and
    degradation windows aside)."""
    p, period = cfg.loss_probability, cfg.period_s
    prob = 1.0
    k = 1
    while k * period <= age_s + 1e-12:
        prob *= p + (1.0 - p) * _delay_exceedance(cfg, age_s - k * period)
        if prob == 0.0:
            break
        k += 1
    return prob


def age_budget_s(cfg: ChannelConfig, quantile: float = AGE_QUANTILE) -> float:
    """The smallest age B with :func:`age_exceedance` (B) ≤ 1 − ``quantile``, s (bisection to 1 ms;
    :data:`AGE_SEARCH_MAX_S` when even that is not enough)."""
    target = 1.0 - quantile
    if age_exceedance(cfg, AGE_SEARCH_MAX_S) > target:
        return AGE_SEARCH_MAX_S
    lo, hi = 0.0, AGE_SEARCH_MAX_S  # the exceedance does not increase with the age
    while hi - lo > 1e-3:
        mid = 0.5 * (lo + hi)
        if age_exceedance(cfg, mid) <= target:
            hi = mid
        else:
            lo = mid
    return hi


class Channel:
    """Delivers messages between trains according to a :class:`ChannelConfig`."""

    def __init__(self, cfg: ChannelConfig | None = None):
        self.cfg = cfg or ChannelConfig()
        if self.cfg.model == "empirical" and not self.cfg.samples_s:
            raise ValueError("empirical channel needs samples_s")
        self.rng = np.random.default_rng(self.cfg.seed)
        self._queue: list[tuple[float, int, str, Message]] = []
        """Messages in flight as (delivery time, send order, receiver, message): a heap."""
        self._seq = 0
        self._last_sent: dict[str, float] = {}
        self._latest: dict[str, dict[str, Message]] = {}
        """receiver -> sender -> latest message delivered (indexed by receiver: a delivery reads only its own links)."""
        self.sent = 0
        self.lost = 0
        self.delivered = 0

    def _window(self, t: float) -> Degradation | None:
        for w in self.cfg.degradations:
            if w.start_s <= t < w.end_s:
                return w
        return None

    def _delay(self, t: float) -> float | None:
        """Delay of a message sent at t, or None if it is lost."""
        c = self.cfg
        deg = self._window(t)
        loss = deg.loss_probability if deg else c.loss_probability
        if loss > 0 and self.rng.random() < loss:
            return None
        if c.model == "ideal":
            base = 0.0
        elif c.model == "constant":
            base = c.delay_s
        elif c.model == "exponential":
            mean = deg.exponential_mean_s if deg is not None and deg.exponential_mean_s is not None else c.mean_extra_s
            base = c.delay_s + (self.rng.exponential(mean) if mean > 0 else 0.0)
        else:
            base = float(self.rng.choice(c.samples_s))
        if deg:
            base += deg.delay_s + (self.rng.exponential(deg.mean_extra_s) if deg.mean_extra_s > 0 else 0.0)
        return base

    def due(self, sender: str, t: float) -> bool:
        """True when ``sender`` should send at time t (every ``period_s``)."""
        last = self._last_sent.get(sender)
        return last is None or t - last >= self.cfg.period_s - 1e-9

    def send(self, msg: Message, receivers: list[str], t: float) -> None:
        """Send ``msg`` (time-stamped t) to each receiver over its own link."""
        self._last_sent[msg.sender] = t
        for r in receivers:
            self.sent += 1
            d = self._delay(t)
            if d is None:
                self.lost += 1
                continue
            self._seq += 1
            heapq.heappush(self._queue, (t + d, self._seq, r, msg))

    def advance(self, t: float) -> None:
        """Deliver every message due by time t (to whichever receiver); :meth:`deliver` does this first."""
        queue = self._queue
        outages = self.cfg.outages
        while queue and queue[0][0] <= t + 1e-9:
            deliver_at, _, receiver, msg = heapq.heappop(queue)
            if outages and (any(w.start_s <= deliver_at < w.end_s for w in outages) or any(w.start_s <= msg.sent_time_s < w.end_s for w in outages)):
                self.lost += 1
                continue
            links = self._latest.get(receiver)
            if links is None:
                links = self._latest[receiver] = {}
            prev = links.get(msg.sender)
            if prev is None or prev.sent_time_s <= msg.sent_time_s:
                if type(msg) is Message:  # (dataclasses.replace without its per-call introspection)
                    links[msg.sender] = Message(msg.sender, msg.sent_time_s, msg.state, msg.length_m, msg.plan_times_s, msg.plan_positions_m,
                                                msg.plan_speeds_mps, msg.plan_forces_n, deliver_at)
                else:
                    links[msg.sender] = replace(msg, received_time_s=deliver_at)
                self.delivered += 1

    def deliver(self, receiver: str, t: float) -> dict[str, Message]:
        """Latest message per sender delivered to ``receiver`` up to time t."""
        self.advance(t)
        return self.latest(receiver)

    def remember(self, receiver: str, msg: Message) -> None:
        """Hold ``msg`` as delivered to ``receiver`` (a link already up when a run starts)."""
        links = self._latest.setdefault(receiver, {})
        prev = links.get(msg.sender)
        if prev is None or prev.sent_time_s <= msg.sent_time_s:
            links[msg.sender] = msg

    def latest(self, receiver: str) -> dict[str, Message]:
        """Latest message per sender delivered to ``receiver`` so far (what the last :meth:`deliver` returned); delivers nothing."""
        links = self._latest.get(receiver)
        return dict(links) if links else {}

    @property
    def loss_ratio(self) -> float:
        return self.lost / self.sent if self.sent else math.nan
