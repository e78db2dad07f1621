"""Tier 2 — the built SUMO network: signals, slopes, lengths, stations, cache."""

import pytest

from vcsumo.sim.network import build_network, fingerprint

pytestmark = pytest.mark.sumo


def test_network_in_sumo_has_every_signal_and_platform(network_factory, tmp_path):
    from vcsumo.sim.sumo_backend import SumoBackend

    net = network_factory("firenze_bologna")
    topo = net.topology
    (tmp_path / "empty.rou.xml").write_text("<routes/>")
    with SumoBackend(["-n", str(net.net_file), "-a", str(net.stations_file), "-r", str(tmp_path / "empty.rou.xml"), "--end", "1", "--no-step-log", "true"]) as sim:
        ls = sim._ls
        tls = set(ls.trafficlight.getIDList())
        assert topo.signal_nodes() == tls
        assert "main_down_n16" in tls  # Bivio Emilia, down track: the junction protecting the diverge
        assert len(ls.busstop.getIDList()) == len(topo.platforms)
        for eid in ("main_up_10", "main_down_40", "san_ruffillo_up_1"):
            assert ls.lane.getLength(eid + "_0") == pytest.approx(topo.edges[eid].length_m, abs=1e-3)
            assert ls.lane.getMaxSpeed(eid + "_0") == pytest.approx(topo.edges[eid].speed_ms, abs=1e-3)


def test_cache_is_reused_and_rebuilt_on_change(tmp_path):
    from vcsumo.line import load_line

    src = (tmp_path / "l" / "line.yaml")
    src.parent.mkdir()
    text = "name: cachetest\nkm_start: 0\nkm_end: 5\nline_speed_kmh: 160\nsignalling: {block_length_m: 1000}\n"
    src.write_text(text)
    a = build_network(load_line(src))
    mtime = a.net_file.stat().st_mtime_ns
    b = build_network(load_line(src))
    assert b.net_file == a.net_file and b.net_file.stat().st_mtime_ns == mtime
    src.write_text(text.replace("160", "120"))
    c = build_network(load_line(src))
    assert c.folder != a.folder and c.fingerprint == fingerprint(load_line(src), None)
    assert 'speed="33.3333"' in c.net_file.read_text() and 'speed="44.4444"' not in c.net_file.read_text()


def test_netconvert_failure_is_one_clear_error(tmp_path, monkeypatch):
    monkeypatch.setenv("VCSUMO_CACHE", str(tmp_path / "cache"))
    from vcsumo.sim import network as network_mod
    from vcsumo.errors import SumoError
    from vcsumo.line import load_line

    src = tmp_path / "l" / "line.yaml"
    src.parent.mkdir()
    src.write_text("name: broken\nkm_start: 0\nkm_end: 5\nline_speed_kmh: 160\nsignalling: {block_length_m: 1000}\n")
    real = network_mod.write_plain_xml

    def corrupt(topo, folder):  # a real netconvert run on an inconsistent connection file
        real(topo, folder)
        (folder / "line.con.xml").write_text('<connections><connection from="nowhere" to="main_up_0"/></connections>')

    monkeypatch.setattr(network_mod, "write_plain_xml", corrupt)
    with pytest.raises(SumoError) as exc:
        build_network(load_line(src), force=True)
    assert str(src) in str(exc.value) and "netconvert failed" in str(exc.value)
    assert not any(p.name.startswith(".") for p in (tmp_path / "cache" / "networks" / "broken").iterdir())
