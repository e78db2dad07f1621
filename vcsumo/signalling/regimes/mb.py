"""Moving block, ETCS Level 3 style: authority to the confirmed rear of the train ahead."""

from __future__ import annotations

from vcsumo.signalling.blocking_time import mb_headway_profile
from vcsumo.signalling.regimes.base import AnalyticHeadway, HeadwayInputs, Regime


class MovingBlock(Regime):
    """MB: SUMO's rail signals in moving-block mode (flank and head-on protection only); the
    movement authority of a train ends at the rear of the train ahead as of its last position
    report, less the safety margin and the position error of both trains, and the train keeps its
    guaranteed braking curve to it.

    H(y) = t(z) − t(y) + P + T_fixed with z = y + D(v(y)) + margin + 2e + L: the follower at y
    needs the rear of the train ahead beyond z, and the report it sees may be a report period P old.
    """

    name = "mb"
    title = "Moving block (ETCS L3-like)"
    moving_block = True
    supervision = "mb"

    def analytic_headway(self, inp: HeadwayInputs, convoy_size: int = 1) -> AnalyticHeadway:
        a = inp.model.assumptions
        prof = mb_headway_profile(inp.run, convoy_size * inp.stock.length_m, inp.braking(), inp.model.margin_m)
        sel = prof[prof.s_m <= inp.s_check_m]
        if sel.empty:
            sel = prof.iloc[:1]
        i = sel.headway_s.idxmax()
        extra = a.position_report_period_s + a.fixed_time_s
        return AnalyticHeadway(float(sel.loc[i, "headway_s"]) + extra, float(sel.loc[i, "s_m"]), reservation=prof[["s_m", "reserved_to_m"]])
