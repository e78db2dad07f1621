"""Communication topologies (survey §II.A, Fig. 5, eq. 4.1–4.2)."""

from __future__ import annotations

import numpy as np
import pytest

from vcsumo.control.topology_graph import TOPOLOGIES, convoy_graph, hop_offset, listens_to

CONVOY = ("L", "A", "B", "C")  # leader first


def test_pf_matrices_for_four_trains():
    g = convoy_graph("PF", 4)
    np.testing.assert_array_equal(g.adjacency, [[0, 0, 0], [1, 0, 0], [0, 1, 0]])
    np.testing.assert_array_equal(g.pinning, [1, 0, 0])
    np.testing.assert_array_equal(g.h_matrix(), [[1, 0, 0], [-1, 1, 0], [0, -1, 1]])


def test_plf_bd_bdl_tpf_matrices_for_four_trains():
    plf = convoy_graph("PLF", 4)
    np.testing.assert_array_equal(plf.adjacency, [[0, 0, 0], [1, 0, 0], [0, 1, 0]])
    np.testing.assert_array_equal(plf.pinning, [1, 1, 1])
    bd = convoy_graph("BD", 4)
    np.testing.assert_array_equal(bd.adjacency, [[0, 1, 0], [1, 0, 1], [0, 1, 0]])
    np.testing.assert_array_equal(bd.pinning, [1, 0, 0])
    bdl = convoy_graph("BDL", 4)
    np.testing.assert_array_equal(bdl.adjacency, bd.adjacency)
    np.testing.assert_array_equal(bdl.pinning, [1, 1, 1])
    tpf = convoy_graph("TPF", 4)
    np.testing.assert_array_equal(tpf.adjacency, [[0, 0, 0], [1, 0, 0], [1, 1, 0]])
    np.testing.assert_array_equal(tpf.pinning, [1, 1, 0])  # train 2's second predecessor is the leader


@pytest.mark.parametrize("topology", TOPOLOGIES)
@pytest.mark.parametrize("n", [2, 3, 4, 7])
def test_consensus_condition_holds(topology, n):
    """Every topology has a spanning tree rooted at the leader, so ℋ = ℒ + 𝒜₀ has eigenvalues with Re > 0."""
    g = convoy_graph(topology, n)
    assert g.leader_reachable()
    lap = g.laplacian()
    np.testing.assert_allclose(lap.sum(axis=1), 0.0)  # Laplacian rows sum to zero
    assert np.all(np.diag(g.adjacency) == 0)
    assert g.h_eigenvalues().real.min() > 0
    assert g.h_eigenvalues(normalized=True).real.min() > 0
    np.testing.assert_allclose(g.full_adjacency()[0], 0.0)  # the leader listens to nobody


@pytest.mark.parametrize("topology", ["PF", "PLF", "TPF"])
def test_acyclic_topologies_have_unit_normalized_spectrum(topology):
    """Information flowing backwards only: ℋ triangular, eq. 4.3's normalisation makes every eigenvalue 1."""
    g = convoy_graph(topology, 6)
    assert g.is_acyclic()
    np.testing.assert_allclose(g.h_eigenvalues(normalized=True), 1.0)


def test_bidirectional_h_is_symmetric_positive_definite():
    g = convoy_graph("BD", 5)
    assert not g.is_acyclic()
    h = g.h_matrix()
    np.testing.assert_allclose(h, h.T)
    assert np.linalg.eigvalsh(h).min() > 0


def test_listens_to():
    assert listens_to("PF", CONVOY, "B") == {"A": 1.0}
    assert listens_to("PLF", CONVOY, "C") == {"L": 1.0, "B": 1.0}
    assert listens_to("BD", CONVOY, "A") == {"L": 1.0, "B": 1.0}
    assert listens_to("BD", CONVOY, "C") == {"B": 1.0}
    assert listens_to("BDL", CONVOY, "B") == {"L": 1.0, "A": 1.0, "C": 1.0}
    assert listens_to("TPF", CONVOY, "C") == {"A": 1.0, "B": 1.0}
    assert listens_to("TPF", CONVOY, "A") == {"L": 1.0}
    assert listens_to("PF", CONVOY, "L") == {}
    assert listens_to("PF", CONVOY, "X") == {}


def test_neighbour_indices_and_hops():
    g = convoy_graph("TPF", 5)
    assert g.neighbours(4) == {2: 1.0, 3: 1.0}
    assert g.neighbours(0) == {}
    assert hop_offset(4, 2) == 2 and hop_offset(1, 2) == -1


def test_bad_inputs():
    with pytest.raises(ValueError, match="unknown topology"):
        convoy_graph("RING", 4)
    with pytest.raises(ValueError, match="at least 2"):
        convoy_graph("PF", 1)
    assert convoy_graph("pf", 3).topology == "PF"
