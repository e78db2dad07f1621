"""Train-to-train communication topologies of a virtually coupled convoy (Wu et al. survey §II.A).

A convoy of ``n_trains`` trains is indexed as in the survey: train 0 is the convoy leader and
trains 1..N (N = n_trains − 1) are the followers, ordered front to back.  The communication graph
among the followers is the digraph 𝒢 = {𝒱, 𝒜, ℰ} of §II.A with adjacency matrix 𝒜 = [a_ij]
(a_ij > 0: train i receives information from train j), and the *pinning* (leader adjacency)
matrix 𝒜₀ = diag{a_10, …, a_N0} says which followers hear the leader (eq. 4.1–4.2).  The
closed-loop convoy (eq. 4.2) is governed by ℋ = ℒ + 𝒜₀, ℒ being the Laplacian of 𝒢.

Topologies (survey Fig. 5 and the road-platoon topologies it adapts, refs. [68-71]):

* ``PF``  predecessor-following: i listens to i−1;
* ``PLF`` predecessor-leader-following: i listens to i−1 and to the leader 0;
* ``BD``  bidirectional: i listens to i−1 and i+1 (Fig. 5 without the leader links);
* ``BDL`` bidirectional-leader (Fig. 5(b)): BD plus every follower listens to the leader;
* ``TPF`` two-predecessor-following (Fig. 5(c)): i listens to i−1 and i−2.

Every topology here contains a directed spanning tree rooted at the leader, so ℋ is nonsingular
and all its eigenvalues have positive real parts (the consensus condition of eq. 4.2).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Literal, Sequence

import numpy as np

TopologyName = Literal["PF", "PLF", "BD", "BDL", "TPF"]
TOPOLOGIES: tuple[str, ...] = ("PF", "PLF", "BD", "BDL", "TPF")


@dataclass(frozen=True)
class ConvoyGraph:
    """Adjacency 𝒜 (followers × followers) and pinning 𝒜₀ of one convoy (survey eq. 4.1–4.2).

    Row/column k of ``adjacency`` and entry k of ``pinning`` belong to follower k+1 (train 0 is
    the leader and has no row: it is driven by its own speed reference, eq. 3.7).
    """

    topology: str
    n_trains: int
    adjacency: np.ndarray
    """a_ij among the followers, shape (N, N), zero diagonal."""
    pinning: np.ndarray
    """a_i0 (1 if follower i hears the leader), shape (N,)."""

    @property
    def n_followers(self) -> int:
        return self.n_trains - 1

    def in_degree(self) -> np.ndarray:
        """η_i = Σ_j a_ij + a_i0, the normaliser 1/Σ a_ij of eq. 4.3, shape (N,)."""
        return self.adjacency.sum(axis=1) + self.pinning

    def laplacian(self) -> np.ndarray:
        """ℒ = 𝒟 − 𝒜 of the follower graph (𝒟 = diag of row sums of 𝒜)."""
        return np.diag(self.adjacency.sum(axis=1)) - self.adjacency

    def h_matrix(self) -> np.ndarray:
        """ℋ = ℒ + 𝒜₀ of the closed loop eq. 4.2."""
        return self.laplacian() + np.diag(self.pinning)

    def normalized_h(self) -> np.ndarray:
        """ℋ̂ = 𝒟_η⁻¹ ℋ: the matrix of eq. 4.2 when every row is divided by Σ a_ij (eq. 4.3)."""
        return self.h_matrix() / self.in_degree()[:, None]

    def h_eigenvalues(self, normalized: bool = False) -> np.ndarray:
        """Eigenvalues of ℋ (or ℋ̂), sorted by real part."""
        ev = np.linalg.eigvals(self.normalized_h() if normalized else self.h_matrix())
        return ev[np.argsort(ev.real)]

    def full_adjacency(self) -> np.ndarray:
        """n×n matrix over all trains (row/col 0 = leader); row 0 is zero (the leader listens to nobody)."""
        n = self.n_trains
        a = np.zeros((n, n))
        a[1:, 1:] = self.adjacency
        a[1:, 0] = self.pinning
        return a

    def neighbours(self, i: int) -> dict[int, float]:
        """Convoy indices (0 = leader) train i listens to, with their weights a_ij."""
        if i <= 0 or i >= self.n_trains:
            return {}
        row = self.full_adjacency()[i]
        return {int(j): float(row[j]) for j in np.flatnonzero(row)}

    def leader_reachable(self) -> bool:
        """True if every follower is reached from the leader by a directed path (ℋ nonsingular)."""
        a = self.full_adjacency()
        reached = {0}
        frontier = [0]
        while frontier:
            j = frontier.pop()
            for i in np.flatnonzero(a[:, j]):
                if int(i) not in reached:
                    reached.add(int(i))
                    frontier.append(int(i))
        return len(reached) == self.n_trains

    def is_acyclic(self) -> bool:
        """True if information only flows backwards (𝒜 strictly lower triangular: PF, PLF, TPF).

        Then ℋ is triangular; with the normalisation of eq. 4.3 all its eigenvalues are 1 and the
        closed loop is a cascade of identical loops, stable for any constant T2T delay.
        """
        return bool(np.allclose(np.triu(self.adjacency), 0.0))


def hop_offset(i: int, j: int) -> int:
    """Signed number of inter-train gaps from train i to train j (positive when j is ahead)."""
    return i - j


@lru_cache(maxsize=256)
def _graph(topology: str, n_trains: int) -> ConvoyGraph:
    if topology not in TOPOLOGIES:
        raise ValueError(f"unknown topology '{topology}' (known: {', '.join(TOPOLOGIES)})")
    if n_trains < 2:
        raise ValueError("a convoy needs at least 2 trains (survey §II.A: N ≥ 2 automated trains incl. leader)")
    n_f = n_trains - 1
    full = np.zeros((n_trains, n_trains))
    for i in range(1, n_trains):
        full[i, i - 1] = 1.0  # every topology has the predecessor link
        if topology in ("PLF", "BDL"):
            full[i, 0] = 1.0
        if topology in ("BD", "BDL") and i + 1 < n_trains:
            full[i, i + 1] = 1.0
        if topology == "TPF" and i >= 2:
            full[i, i - 2] = 1.0
    adjacency = full[1:, 1:].copy()
    pinning = full[1:, 0].copy()
    adjacency.setflags(write=False)
    pinning.setflags(write=False)
    g = ConvoyGraph(topology=topology, n_trains=n_trains, adjacency=adjacency, pinning=pinning)
    assert g.leader_reachable()
    assert adjacency.shape == (n_f, n_f)
    return g


def convoy_graph(topology: str, n_trains: int) -> ConvoyGraph:
    """The communication graph of a convoy of ``n_trains`` (leader included), unit weights a_ij = 1."""
    return _graph(str(topology).upper(), int(n_trains))


def listens_to(topology: str, convoy: Sequence[str], ego: str) -> dict[str, float]:
    """Train ids that ``ego`` listens to in ``convoy`` (leader first), with weights a_ij (eq. 4.1).

    The convoy leader listens to nobody (empty dict); so does a train not in the convoy.
    """
    convoy = tuple(convoy)
    if ego not in convoy or len(convoy) < 2:
        return {}
    g = convoy_graph(topology, len(convoy))
    return {convoy[j]: w for j, w in g.neighbours(convoy.index(ego)).items()}
