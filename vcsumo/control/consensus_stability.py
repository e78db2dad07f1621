"""Linear analysis of the consensus-controlled convoy (eq. 4.2 with the T2T delay of eq. 4.3).

The follower is linearised to the third-order model (τs + 1)s²X_i = U_i (leader exogenous, its speed
broadcast); :func:`closed_loop_stable` and :func:`delay_margin_s` test internal stability with a
constant delay (generalised Nyquist), :func:`string_gain` and :func:`string_stability_delay_bound_s`
the PF cascade's string stability (sup|G(jω)| ≤ 1), :func:`leader_response` the response of every
follower to the leader, :func:`closed_loop_poles` the delay-free poles.  The tests use them to
justify the delay bound and the string-stability condition of the gains in ``controllers/cbc.yaml``.
"""

from __future__ import annotations

import math

import numpy as np

from vcsumo.control.consensus_params import CbcParams
from vcsumo.control.topology_graph import ConvoyGraph, convoy_graph


def _loop_matrices(prm: CbcParams, graph: ConvoyGraph, lag_s: float, delay_s: float) -> tuple[list[np.ndarray], np.ndarray]:
    """Own polynomials q_i(s) and neighbour polynomials p_ij(s) (highest power first).

    Linearised follower i (plant (τs+1)s²X_i = U_i, leader exogenous, leader speed broadcast):
        q_i(s) X_i − e^{−sθ} Σ_{j≥1} p_ij(s) X_j = (leader terms)
        q_i = τs³ + (1 + k_a0 + k_a Σw)s² + (k_v Σw + k_v0 + k_x h Σ_j w_ij (i−j))s + k_x Σw
        p_ij = w_ij (k_a s² + (k_v + k_x θ [sender compensation]) s + k_x) + w̄_ij c_ff s²
    """
    n_f = graph.n_followers
    tau = max(lag_s, 1e-3)
    full = graph.full_adjacency()
    eta = graph.in_degree()
    qs: list[np.ndarray] = []
    P = np.zeros((n_f, n_f, 3))
    theta_s = delay_s if prm.delay_compensation == "sender" else 0.0
    for r in range(n_f):
        i = r + 1
        row = full[i]
        w = row / eta[r] if prm.normalize else row.copy()
        wbar = row / eta[r]
        sw = w.sum()
        sigma = sum(w[j] * (i - j) for j in range(graph.n_trains))
        qs.append(np.array([tau, 1 + prm.k_own_acc + prm.k_acc * sw, prm.k_vel_per_s * sw + prm.k_ref_vel_per_s + prm.k_pos_per_s2 * prm.gap.headway_s * sigma, prm.k_pos_per_s2 * sw]))
        for j in range(1, graph.n_trains):
            if row[j] > 0:
                P[r, j - 1] = w[j] * np.array([prm.k_acc, prm.k_vel_per_s + prm.k_pos_per_s2 * theta_s, prm.k_pos_per_s2]) + wbar[j] * np.array([prm.accel_feedforward, 0.0, 0.0])
    return qs, P


def _omega_grid(n: int = 4000, w_min: float = 1e-4, w_max: float = 200.0) -> np.ndarray:
    return np.concatenate([[0.0], np.logspace(math.log10(w_min), math.log10(w_max), n)])


def closed_loop_stable(prm: CbcParams, n_trains: int, lag_s: float, delay_s: float = 0.0) -> bool:
    """Is the linearised convoy (eq. 4.2) with constant T2T delay θ = ``delay_s`` asymptotically stable?

    Generalised Nyquist criterion: with every own loop q_i Hurwitz, the quasi-polynomial
    det(Q(s) − e^{−sθ}P(s)) has no root in Re s ≥ 0 iff det(I − e^{−jωθ}Q⁻¹P(jω)) does not encircle 0.
    """
    graph = convoy_graph(prm.topology, n_trains)
    qs, P = _loop_matrices(prm, graph, lag_s, delay_s)
    for q in qs:
        if np.any(np.roots(q).real >= 0):
            return False
    w = _omega_grid()
    s = 1j * w
    qv = np.stack([np.polyval(q, s) for q in qs], axis=1)  # (W, N)
    pv = P[..., 0][None] * s[:, None, None] ** 2 + P[..., 1][None] * s[:, None, None] + P[..., 2][None]
    g = np.exp(-s * delay_s)[:, None, None] * pv / qv[:, :, None]
    n_f = graph.n_followers
    det = np.linalg.det(np.eye(n_f)[None] - g)
    if np.min(np.abs(det)) < 1e-9:
        return False
    phase = np.unwrap(np.angle(det))
    winding = 2.0 * (phase[-1] - phase[0]) / (2 * math.pi)
    return abs(winding) < 0.5


def delay_margin_s(prm: CbcParams, n_trains: int, lag_s: float, max_delay_s: float = 10.0, step_s: float = 0.1) -> float:
    """Smallest constant T2T delay that destabilises the linearised convoy, s (inf if none ≤ ``max_delay_s``).

    For acyclic topologies (PF, PLF, TPF) Q⁻¹P is nilpotent, det ≡ 1, and the margin is infinite:
    the delay can only degrade string stability (:func:`string_gain`), not internal stability.
    """
    if not closed_loop_stable(prm, n_trains, lag_s, 0.0):
        return 0.0
    if convoy_graph(prm.topology, n_trains).is_acyclic():
        return math.inf  # Q⁻¹P strictly lower triangular: det(I − e^{−sθ}Q⁻¹P) ≡ 1 for every θ
    theta = step_s
    prev = 0.0
    while theta <= max_delay_s + 1e-12:
        if not closed_loop_stable(prm, n_trains, lag_s, theta):
            lo, hi = prev, theta
            for _ in range(20):
                mid = 0.5 * (lo + hi)
                if closed_loop_stable(prm, n_trains, lag_s, mid):
                    lo = mid
                else:
                    hi = mid
            return 0.5 * (lo + hi)
        prev = theta
        theta += step_s
    return math.inf


def leader_response(prm: CbcParams, n_trains: int, lag_s: float, omega_rad_s: np.ndarray, delay_s: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Frequency responses from the leader's position X_0 to every follower, linearised (eq. 4.2 with delay θ).

    Solves (Q(jω) − e^{−jωθ}P(jω)) X = b(jω) X_0, where b collects everything follower i receives from
    the leader: the pinning link a_i0 (k_x, k_v, k_a, c_ff, its delay compensation), the eq. 4.3
    reference-speed compensation θ·v_0 on every link, and k_v0·v_0.  Returns (X_i/X_0, E_i/X_0), each of
    shape (N, len(ω)), with the gap error E_i = X_{i−1} − X_i − h·s·X_i (constant time headway, eq. 3.1).
    """
    graph = convoy_graph(prm.topology, n_trains)
    qs, P = _loop_matrices(prm, graph, lag_s, delay_s)
    n_f = graph.n_followers
    full = graph.full_adjacency()
    eta = graph.in_degree()
    w = np.asarray(omega_rad_s, dtype=float)
    s = 1j * w
    z = np.exp(-s * delay_s)
    comp_leader = prm.delay_compensation in ("reference", "sender")
    b = np.zeros((len(w), n_f), dtype=complex)
    for r in range(n_f):
        row = full[r + 1]
        wr = row / eta[r] if prm.normalize else row.copy()
        wbar0 = row[0] / eta[r]
        k_v = prm.k_vel_per_s + (prm.k_pos_per_s2 * delay_s if comp_leader else 0.0)
        bi = wr[0] * (prm.k_acc * s**2 + k_v * s + prm.k_pos_per_s2) + wbar0 * prm.accel_feedforward * s**2
        if prm.delay_compensation == "reference":
            bi = bi + wr[1:].sum() * prm.k_pos_per_s2 * delay_s * s
        bi = bi + prm.k_ref_vel_per_s * s
        b[:, r] = z * bi
    M = np.zeros((len(w), n_f, n_f), dtype=complex)
    for r, q in enumerate(qs):
        M[:, r, r] = np.polyval(q, s)
    M -= z[:, None, None] * (P[..., 0][None] * s[:, None, None] ** 2 + P[..., 1][None] * s[:, None, None] + P[..., 2][None])
    X = np.linalg.solve(M, b[..., None])[..., 0]  # (W, N)
    ahead = np.concatenate([np.ones((len(w), 1)), X[:, :-1]], axis=1)
    E = ahead - X - prm.gap.headway_s * s[:, None] * X
    return X.T, E.T


def string_gain_response(prm: CbcParams, lag_s: float, omega_rad_s: np.ndarray, delay_s: float = 0.0) -> np.ndarray:
    """|G(jω)| of the PF predecessor→follower transfer (homogeneous string, linearised), -.

    G(s) = e^{−sθ} p(s)/q(s) with the PF row of :func:`_loop_matrices`.  With compensation ``none``
    or ``sender`` (or no delay) the PF string is a pure cascade: positions and gap errors of
    consecutive followers are related by G, so a disturbance at frequency ω is multiplied by
    |G(jω)| from one follower to the next.  With the eq. 4.3 ``reference`` compensation and θ > 0
    every follower also receives θ·v_0 from the leader (an extra path): use :func:`leader_response`.
    """
    qs, P = _loop_matrices(prm.model_copy(update={"topology": "PF"}), convoy_graph("PF", 3), lag_s, delay_s)
    s = 1j * np.asarray(omega_rad_s, dtype=float)
    return np.abs(np.polyval(P[1, 0], s) / np.polyval(qs[1], s))


def string_gain_peak(prm: CbcParams, lag_s: float, delay_s: float = 0.0) -> tuple[float, float]:
    """(sup_ω |G(jω)|, the ω in rad/s where it is reached) for the PF string (see :func:`string_gain_response`)."""
    w = _omega_grid(20000)[1:]
    g = string_gain_response(prm, lag_s, w, delay_s)
    k = int(np.argmax(g))
    return float(g[k]), float(w[k])


def string_gain(prm: CbcParams, lag_s: float, delay_s: float = 0.0) -> float:
    """sup_ω |G(jω)|: the PF cascade is (L2) string stable iff it is ≤ 1 (G(0) = 1 always)."""
    return string_gain_peak(prm, lag_s, delay_s)[0]


def string_stability_delay_bound_s(prm: CbcParams, lag_s: float, max_delay_s: float = 10.0, tol: float = 1e-6) -> float:
    """Largest constant delay keeping the PF cascade string stable (sup|G| ≤ 1), s.

    0 if not string stable without delay, inf if never lost up to ``max_delay_s``.  Only defined for
    cascades (compensation ``none`` or ``sender``): with ``reference`` G does not depend on θ and the
    delay acts through the leader path instead (see :func:`leader_response`).
    """
    if prm.delay_compensation == "reference":
        raise ValueError("with reference-speed compensation the PF string is not a pure cascade: use leader_response")
    if string_gain(prm, lag_s, 0.0) > 1.0 + tol:
        return 0.0
    if string_gain(prm, lag_s, max_delay_s) <= 1.0 + tol:
        return math.inf
    lo, hi = 0.0, max_delay_s
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        if string_gain(prm, lag_s, mid) <= 1.0 + tol:
            lo = mid
        else:
            hi = mid
    return lo


def closed_loop_poles(prm: CbcParams, n_trains: int, lag_s: float) -> np.ndarray:
    """Eigenvalues of the delay-free linearised convoy (eq. 4.2; state [x, v, a] per follower), 1/s."""
    graph = convoy_graph(prm.topology, n_trains)
    qs, P = _loop_matrices(prm, graph, lag_s, 0.0)
    n_f = graph.n_followers
    A = np.zeros((3 * n_f, 3 * n_f))
    for r, q in enumerate(qs):
        tau = q[0]
        A[3 * r, 3 * r + 1] = 1.0
        A[3 * r + 1, 3 * r + 2] = 1.0
        A[3 * r + 2, 3 * r : 3 * r + 3] = -q[[3, 2, 1]] / tau
        for c in range(n_f):
            A[3 * r + 2, 3 * c : 3 * c + 3] += P[r, c][[2, 1, 0]] / tau
    return np.linalg.eigvals(A)


def settling_rate_per_s(prm: CbcParams, n_trains: int, lag_s: float) -> float:
    """−max Re of the delay-free closed-loop poles (:func:`closed_loop_poles`): errors decay like e^{−rate·t}, 1/s."""
    return float(-closed_loop_poles(prm, n_trains, lag_s).real.max())
