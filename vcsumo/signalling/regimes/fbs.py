"""Fixed block, ETCS Level 2 style: authority to the last signal an overlap behind the train ahead."""

from __future__ import annotations

from vcsumo.signalling.blocking_time import fbs_blocking_times
from vcsumo.signalling.regimes.base import AnalyticHeadway, HeadwayInputs, Regime


class FixedBlock(Regime):
    """FBS: SUMO's rail signals with fixed blocks; the movement authority of a train ends at the
    last signal that lies at least ``overlap_m`` (plus the position error of the train ahead) behind
    the rear of the train ahead, and the train plans to stop its own position error short of it on
    its guaranteed braking curve.

    Blocking time of block k (signal S_k to S_k+1): from the moment the follower must be able to
    stop before S_k — its position a with a + D(v(a)) + e = S_k — until the leader's rear is
    ``overlap + e`` beyond S_k+1, plus the fixed times:
    H_k = t(S_k+1 + overlap + e + L) − t(a_k) + T_fixed.
    """

    name = "fbs"
    title = "Fixed block (ETCS L2-like)"
    moving_block = False
    supervision = "fbs"

    def analytic_headway(self, inp: HeadwayInputs, convoy_size: int = 1) -> AnalyticHeadway:
        a = inp.model.assumptions
        length = convoy_size * inp.stock.length_m
        blocks = fbs_blocking_times(inp.run, [x for x in inp.signals_m if x < inp.end_m - 1e-6], inp.end_m, length, inp.braking(),
                                    approach_offset_m=a.position_error_m, clear_offset_m=a.overlap_m + a.position_error_m)
        sel = blocks[blocks.approach_m <= inp.s_check_m]
        if sel.empty:  # nothing approached yet: the first block is the first constraint
            sel = blocks.iloc[:1]
        i = sel.blocking_time_s.idxmax()
        return AnalyticHeadway(float(sel.loc[i, "blocking_time_s"]) + a.fixed_time_s, float(sel.loc[i, "block_start_m"]), blocks)
