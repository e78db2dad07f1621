"""Why the paper's ≈ 1,300 m (Terlizzi et al. 2024, §VII, OS1 at 50 m/s, Fig. 5b) cannot be matched
with the paper's own equations (README, Reproductions of the seed papers, item 1).

Eq. 15 on Table III's proxies (the shipped ``terlizzi2024_os1_08s`` file, convention ``paper``) is
zero at equal speeds 50 m/s only from L^L + d + S^F − S^L front to front.  Hand bound: the follower's
weakest proxy brakes at no more than ē^F = 0.578 m/s², the leader's strongest at no less than
e̲^L = 0.713 m/s² (its value at 50 m/s; its power-limited brake only grows as it slows), so
S^F ≈ 50²/(2·0.578) = 2,162.6 m (the proxy: 2,161.7 m; 0.578 is rounded) and S^L ≤ 50²/(2·0.713) = 1,753.2 m, and the
zero lies beyond 202 + 1,000 + 2,161 − 1,753 ≈ 1,610 m: 1,300 m is inside the paper's unsafe set,
far outside the 10 % the authors' conventions are held to (test_experiment.py)."""

import pytest

from vcsumo.sim.offline import flat_profile
from vcsumo.studies.experiment import load_experiment
from vcsumo.studies.experiment_build import build_setup

PAPER_COUPLED_M = 1300.0  # §VII-B: "approximately 1300m" (leader to follower, front to front)


def _zero_gap(model, v: float) -> float:
    lo, hi = 300.0, 6000.0
    f = lambda g: model.value(20000.0, v, 20000.0 - g, v)[0]  # noqa: E731
    assert f(lo) > 0 > f(hi)
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if f(mid) > 0 else (lo, mid)
    return 0.5 * (lo + hi)


def test_the_papers_barrier_excludes_the_papers_coupled_distance():
    path, _, runs = load_experiment("terlizzi2024_os1_08s")
    sup = build_setup(runs[0][1], 1, path.parent, path).followers[0].stack.supervisor
    assert sup.cfg.convention == "paper" and sup.cfg.safety_distance_m == 1000.0
    model = sup.model_for(flat_profile(200000.0, 83.0))
    v = 50.0
    s_l = model.leader_stop(20000.0, v) - 20000.0
    s_f = model.follower_stop(20000.0, v, 0.0) - 20000.0
    assert s_f >= v**2 / (2 * 0.578) - 1.0  # ē^F = 0.578 m/s² (Table III at 50 m/s; 1 m of rounding of 0.578)
    assert s_l <= v**2 / (2 * 0.713)  # e̲^L ≥ 0.713 m/s² all the way down
    zero = _zero_gap(model, v)
    assert zero == pytest.approx(202.0 + 1000.0 + s_f - s_l, abs=0.1)
    assert zero >= 202.0 + 1000.0 + v**2 / (2 * 0.578) - v**2 / (2 * 0.713) - 1.0
    assert zero > 1.10 * PAPER_COUPLED_M  # the paper's figure, even with 10 %, is unsafe under its own eq. 15
    assert model.value(20000.0, v, 20000.0 - PAPER_COUPLED_M, v)[0] > 0.0
