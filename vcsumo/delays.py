"""Primary delays: random departure delays at the origin and dwell extensions at stops.

A *primary* delay is one a train suffers on its own (late departure from the origin, a longer dwell
because of passengers, a door fault); a *secondary* (knock-on) delay is one it suffers because of
other trains.  A batch experiment injects primary delays into the planned trains before the
simulation and measures the knock-on delays the timetable and the signalling regime produce.

Configuration (YAML, every key optional, unknown keys are errors; times in s)::

    origin:                 # departure delay at the origin
      probability: 0.3      # share of trains delayed
      distribution: exponential
      mean_s: 120
    dwell:                  # extension of the dwell at each intermediate stop
      probability: 0.1      # share of stops extended
      distribution: uniform
      min_s: 10
      max_s: 60
      cap_s: 600            # optional upper bound of a drawn delay

``distribution`` is one of

* ``exponential`` — ``mean_s`` (the usual model of primary delays, e.g. Yuan & Hansen 2007);
* ``uniform`` — between ``min_s`` and ``max_s``;
* ``empirical`` — one of ``samples_s`` (observed delays), each equally likely;
* ``none`` — no delay (``probability`` is ignored).

The defaults are 30 % of trains delayed at their origin (exponential, mean 120 s) and 10 % of
stops extended (exponential, mean 30 s).

Determinism and common random numbers
-------------------------------------
Every train draws from its own generator, seeded from (timetable digest, seed, train id), so the
delays depend only on the timetable file, the seed and the configuration — never on the regime,
the controller, the other trains or the order of the runs: FBS, MB and VC see exactly the same
primary delays.  Each train always draws the same uniform numbers (two for the origin, two per
stop) and turns them into delays by inverse transform, so for the same seed a larger mean, a
larger probability or a larger sample gives every train a delay at least as large (runs are
compared on common random numbers).
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import Field, model_validator

from vcsumo.config import StrictModel, load_model
from vcsumo.timetable import PlannedTrain

Distribution = Literal["exponential", "uniform", "empirical", "none"]


class DelaySpec(StrictModel):
    """Where a delay occurs with which probability, and how large it is."""

    probability: float = Field(default=0.0, ge=0.0, le=1.0, description="Probability that a train (origin) or a stop (dwell) is delayed, -")
    distribution: Distribution = Field(default="exponential", description="exponential, uniform, empirical or none")
    mean_s: float | None = Field(default=None, gt=0, le=86400, description="Mean of the exponential distribution, s")
    min_s: float | None = Field(default=None, ge=0, le=86400, description="Lower bound of the uniform distribution, s")
    max_s: float | None = Field(default=None, ge=0, le=86400, description="Upper bound of the uniform distribution, s")
    samples_s: list[float] | None = Field(default=None, description="Observed delays (empirical distribution), s")
    cap_s: float | None = Field(default=None, gt=0, le=86400, description="Upper bound of any drawn delay, s")

    @model_validator(mode="after")
    def _parameters_match_distribution(self) -> "DelaySpec":
        used = {
            "exponential": {"mean_s"},
            "uniform": {"min_s", "max_s"},
            "empirical": {"samples_s"},
            "none": set(),
        }[self.distribution]
        for name in ("mean_s", "min_s", "max_s", "samples_s"):
            if getattr(self, name) is not None and name not in used:
                raise ValueError(f"{name} does not apply to distribution '{self.distribution}' (it takes: {', '.join(sorted(used)) or 'nothing'})")
        if self.distribution == "exponential" and self.mean_s is None:
            raise ValueError("distribution 'exponential' needs mean_s")
        if self.distribution == "uniform":
            if self.min_s is None or self.max_s is None:
                raise ValueError("distribution 'uniform' needs min_s and max_s")
            if self.max_s < self.min_s:
                raise ValueError(f"max_s ({self.max_s}) is below min_s ({self.min_s})")
        if self.distribution == "empirical":
            if not self.samples_s:
                raise ValueError("distribution 'empirical' needs a non-empty list samples_s")
            if any(not math.isfinite(x) or x < 0 for x in self.samples_s):
                raise ValueError("samples_s must be finite delays >= 0 s")
        return self

    def quantile(self, u: float) -> float:
        """Inverse CDF: the delay for a uniform number u in [0, 1), s (monotone in u)."""
        if self.distribution == "none":
            return 0.0
        if self.distribution == "exponential":
            x = -float(self.mean_s) * math.log1p(-min(u, 1.0 - 1e-12))
        elif self.distribution == "uniform":
            x = float(self.min_s) + u * (float(self.max_s) - float(self.min_s))
        else:
            xs = sorted(self.samples_s or [0.0])
            x = float(xs[min(int(u * len(xs)), len(xs) - 1)])
        if self.cap_s is not None:
            x = min(x, float(self.cap_s))
        return x

    def draw(self, u_hit: float, u_size: float) -> float:
        """Delay for one train or stop from two uniform numbers, s (0 when not hit)."""
        if self.distribution == "none" or u_hit >= self.probability:
            return 0.0
        return self.quantile(u_size)


class DelayConfig(StrictModel):
    """Primary delays of a batch experiment (file: ``--delay-config``)."""

    description: str = ""
    origin: DelaySpec = Field(default_factory=lambda: DelaySpec(probability=0.3, distribution="exponential", mean_s=120.0),
                              description="Departure delay at the origin (per train)")
    dwell: DelaySpec = Field(default_factory=lambda: DelaySpec(probability=0.1, distribution="exponential", mean_s=30.0),
                             description="Dwell extension at each intermediate stop (per stop)")


NO_DELAYS = DelayConfig(origin=DelaySpec(distribution="none"), dwell=DelaySpec(distribution="none"))


def load_delay_config(path: str | Path | None) -> DelayConfig:
    """The delay configuration in ``path`` (defaults when None); errors name the file and field."""
    if path is None:
        return DelayConfig()
    return load_model(DelayConfig, path)


def config_digest(cfg: DelayConfig) -> str:
    """SHA-256 of the configuration's canonical JSON (the description is not part of it)."""
    data = cfg.model_dump(mode="json", exclude={"description"})
    return hashlib.sha256(json.dumps(data, sort_keys=True, separators=(",", ":")).encode()).hexdigest()


@dataclass(frozen=True)
class TrainDelays:
    """The primary delays injected into one train."""

    train: str
    origin_s: float
    dwell_s: tuple[float, ...]
    """Extension at each intermediate stop, in running order, s."""

    @property
    def total_s(self) -> float:
        return self.origin_s + sum(self.dwell_s)


def train_rng(timetable_digest: str, seed: int, train_id: str) -> np.random.Generator:
    """The generator of one train: depends only on (timetable digest, seed, train id)."""
    h = hashlib.sha256(f"{timetable_digest}|{int(seed)}|{train_id}".encode()).digest()
    return np.random.default_rng(int.from_bytes(h[:16], "big"))


def draw_delays(trains: list[PlannedTrain], cfg: DelayConfig, seed: int, timetable_digest: str) -> dict[str, TrainDelays]:
    """Primary delays of every train (see the module docstring for determinism)."""
    out: dict[str, TrainDelays] = {}
    for t in trains:
        rng = train_rng(timetable_digest, seed, t.id)
        u = rng.random(2 + 2 * len(t.stops))
        d0 = cfg.origin.draw(float(u[0]), float(u[1]))
        dwell = tuple(cfg.dwell.draw(float(u[2 + 2 * k]), float(u[3 + 2 * k])) for k in range(len(t.stops)))
        out[t.id] = TrainDelays(t.id, round(d0, 1), tuple(round(x, 1) for x in dwell))
    return out


def apply_delays(trains: list[PlannedTrain], delays: dict[str, TrainDelays]) -> list[PlannedTrain]:
    """New planned trains: departure later by the origin delay, dwells longer by the extensions.

    Scheduled times (stop arrival/departure, final arrival) are unchanged: they are what the
    delays are measured against.  A dwell extension is a longer *minimum* dwell, so slack in the
    schedule (a train early at a stop with a scheduled departure) absorbs it, as in operation.

    Every train is a copy, its stops too, delayed or not: the run (the VC driver moves convoy
    departures in place) must not move the timetable the delays are measured against (until
    2026-12-01 a train without a delay was the timetable's own object: a follower made to wait for
    its late leader was measured against its moved departure, its knock-on delay hidden).
    """
    out = []
    for t in trains:
        d = delays.get(t.id)
        if d is None or d.total_s == 0.0:
            out.append(replace(t, stops=[replace(s) for s in t.stops]))
            continue
        stops = [replace(s, dwell_s=s.dwell_s + ext) for s, ext in zip(t.stops, d.dwell_s)]
        out.append(replace(t, depart_s=t.depart_s + d.origin_s, stops=stops))
    return out


def inject_delays(trains: list[PlannedTrain], cfg: DelayConfig, seed: int, timetable_digest: str) -> tuple[list[PlannedTrain], dict[str, TrainDelays]]:
    """Draw and apply primary delays; returns (delayed trains, delays per train)."""
    delays = draw_delays(trains, cfg, seed, timetable_digest)
    return apply_delays(trains, delays), delays
