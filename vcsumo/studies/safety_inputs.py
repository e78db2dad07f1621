"""The safety campaign's lines and trains, checked against each other before anything runs.

A line and a train the campaign cannot use are refused with one line naming the file and the
field (exit status 2), never found scenario by scenario:

* a line that can draw none of the kinds asked for (``--kinds``) — merge and split need a junction
  on the line's main track; until 2026-11-28 a line without one silently ran ``cruise`` scenarios
  instead and reported the bar met (with other kinds asked for too, such a line draws those only);
* a train that can be drawn on a line (the line's ``default_train``, and the ``--rolling-stock``
  when convoys are drawn from it) whose guaranteed service brake does not hold it on a descent of
  the line (:class:`~vcsumo.signalling.separation.RouteBraking`: no run of it can be safe; before,
  every scenario drawing it failed on its own row), or that cannot start on a grade of the line
  (:func:`~vcsumo.running_time.stall_problem`: it stalls; before, its scenarios ran and were
  reported clean).
"""

from __future__ import annotations

from vcsumo.errors import InfeasibleBraking, InputError
from vcsumo.running_time import stall_problem
from vcsumo.signalling.separation import RouteBraking, SeparationModel
from vcsumo.studies.safety_scenarios import SafetyCampaign, campaign_assumptions, line_route, stock


def _drawn_trains(cfg: SafetyCampaign, default_train: str) -> list[tuple[str, str]]:
    """(train spec, field that names it) of every train a scenario on the line can draw."""
    trains = [] if cfg.heterogeneous_probability >= 1.0 else [(default_train, "default_train")]
    if cfg.heterogeneous_probability > 0.0:
        trains += [(t, "--rolling-stock") for t in cfg.rolling_stock]
    return trains


def check_lines_and_trains(cfg: SafetyCampaign) -> None:
    """Refuse (:class:`InputError`) a line that cannot draw a requested kind, or a train a line cannot run
    (see the module doc)."""
    aset = campaign_assumptions(cfg.assumptions)
    for ln in cfg.lines:
        for direction in ("up", "down"):
            route = line_route(ln, direction)
            kinds = [k for k in cfg.drawn_kinds if k in ("cruise", "forming") or route.junctions]
            if not kinds:
                raise InputError(ln, "branches", f"no junction on its main track ({direction}): the campaign's kinds "
                                 f"{', '.join(cfg.drawn_kinds)} cannot be drawn on this line (add cruise or forming to --kinds, or a branch)")
            prof = route.profile
            for spec, field in _drawn_trains(cfg, route.stock_spec):
                train = stock(spec)
                where = f"line {route.line} ({direction})"
                try:
                    RouteBraking(SeparationModel(aset), train, prof, "service")
                except InfeasibleBraking as exc:
                    raise InputError(spec if field == "--rolling-stock" else ln, field if field == "default_train" else "service_brake_decel_mps2",
                                     f"{exc} of {where} under the assumption set '{aset.name}': no run of it can be safe") from None
                stall = stall_problem(train.params(), prof, min(train.length_m + 1.0, prof.length_m), prof.length_m)
                if stall:
                    raise InputError(spec if field == "--rolling-stock" else ln, field if field == "default_train" else "max_traction_n",
                                     f"{train.name} {stall} ({where})")


__all__ = ["check_lines_and_trains"]
