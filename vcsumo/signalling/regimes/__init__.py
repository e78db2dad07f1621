"""Signalling regimes registered by name: a new regime is one module here plus one line below.

A :class:`~vcsumo.signalling.regimes.base.Regime` says everything the rest of vcsumo needs to run
and to predict it:

* ``moving_block`` — the SUMO option (rail signals in moving-block mode) its runs use;
* ``supervision`` — how the movement authority of the trains SUMO drives ends
  (:mod:`vcsumo.sim.supervision`: 'fbs' at a signal with overlap, 'mb' at the confirmed rear);
* ``couples`` — whether a vcsumo driver couples convoy followers (VC);
* ``default_step_s`` — the simulation step its runs use unless told otherwise;
* :meth:`~vcsumo.signalling.regimes.base.Regime.analytic_headway` — its minimum headway from the
  separation model alone (never from a simulation), for units of ``convoy_size`` trains.

All regimes take their braking from the one separation model (:mod:`vcsumo.signalling.separation`)
under a named assumption set, so they are compared under the same assumptions.
"""

from __future__ import annotations

from vcsumo.errors import InputError
from vcsumo.signalling.regimes.base import AnalyticHeadway, HeadwayInputs, Regime, SupervisedBraking
from vcsumo.signalling.regimes.fbs import FixedBlock
from vcsumo.signalling.regimes.mb import MovingBlock
from vcsumo.signalling.regimes.vc import VirtualCoupling

REGIMES: dict[str, Regime] = {r.name: r for r in (FixedBlock(), MovingBlock(), VirtualCoupling())}
"""Every registered regime by name (the order is the order of tables and plots)."""


def regime_names() -> tuple[str, ...]:
    return tuple(REGIMES)


def get_regime(name: str, field: str = "--regime") -> Regime:
    """The regime registered as ``name``; an InputError naming ``field`` otherwise."""
    try:
        return REGIMES[name]
    except KeyError:
        raise InputError(None, field, f"unknown regime '{name}' (choose from {', '.join(REGIMES)})") from None


__all__ = ["REGIMES", "AnalyticHeadway", "HeadwayInputs", "Regime", "SupervisedBraking", "get_regime", "regime_names"]
