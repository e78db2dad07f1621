"""The house rules (issue 9), checked on the source: floors, no import cycles, no private names
used across modules, small modules.

Floors, lowest first; a module may import only from its own floor or below:

0. ground — units, errors, config, results, dynamics, line, topology, route_profile, rolling_stock,
   plant, running_time, timetable, delays, log
1. ``signalling`` (regimes, separation model, blocking time, UIC 406, fixed times) and ``plots``
   (read only results tables)
2. ``control`` (controllers, supervisors, channel, registry: no libsumo)
3. ``sim`` (the SUMO loop — the only libsumo user — network builder, VC driver, offline loop)
4. ``engine`` (campaigns of many runs)
5. ``studies`` and ``reproduce``
6. ``cli`` (and ``vcsumo.__main__``, ``python -m vcsumo``)
"""

from __future__ import annotations

import ast
from pathlib import Path



PKG = Path(__file__).resolve().parent.parent / "vcsumo"
FLOORS = {"signalling": 1, "plots": 1, "control": 2, "sim": 3, "engine": 4, "studies": 5, "reproduce": 5, "cli": 6, "__main__": 6}
MAX_LINES = 500
LONG_MODULES = {
    # module: why it is longer than MAX_LINES (each entry is a debt with a reason, not a licence)
}


def _modules() -> dict[str, Path]:
    mods = {}
    for f in PKG.rglob("*.py"):
        parts = f.relative_to(PKG.parent).with_suffix("").parts
        name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        mods[name] = f
    return mods


def _floor(mod: str) -> int:
    parts = mod.split(".")
    return FLOORS.get(parts[1], 0) if len(parts) > 1 else 0


def _imports(mod: str, path: Path, mods: dict[str, Path]) -> list[tuple[str, list[str], int]]:
    """(imported module, imported names, line) for every vcsumo import of a module."""
    pkg = mod if path.name == "__init__.py" else mod.rsplit(".", 1)[0]
    out = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = pkg.split(".")[: len(pkg.split(".")) - (node.level - 1)]
                base = ".".join(parts + ([base] if base else []))
            if not base.startswith("vcsumo"):
                continue
            names = [a.name for a in node.names]
            subs = [f"{base}.{n}" for n in names if f"{base}.{n}" in mods]
            if subs:
                out += [(s, [], node.lineno) for s in subs]
                names = [n for n in names if f"{base}.{n}" not in mods]
            if base in mods:
                out.append((base, names, node.lineno))
        elif isinstance(node, ast.Import):
            out += [(a.name, [], node.lineno) for a in node.names if a.name in mods]
    return out


def test_no_module_imports_from_a_higher_floor():
    mods = _modules()
    bad = [f"{m} (floor {_floor(m)}) imports {t} (floor {_floor(t)}) at line {ln}"
           for m, p in mods.items() for t, _, ln in _imports(m, p, mods) if _floor(t) > _floor(m)]
    assert not bad, "\n".join(bad)


def test_import_graph_is_acyclic():
    mods = _modules()
    edges = {m: {t for t, _, _ in _imports(m, p, mods) if t != m and not mods[t].name == "__init__.py"} for m, p in mods.items()}
    cycles, state = [], {}

    def visit(v, stack):
        state[v] = 1
        for w in edges[v]:
            if state.get(w) == 1:
                cycles.append(" -> ".join(stack[stack.index(w):] + [w]))
            elif w not in state:
                visit(w, stack + [w])
        state[v] = 2

    for v in sorted(edges):
        if v not in state:
            visit(v, [v])
    assert not cycles, "\n".join(cycles)


def test_no_private_name_used_outside_its_module():
    mods = _modules()
    bad = []
    for m, p in mods.items():
        for t, names, ln in _imports(m, p, mods):
            bad += [f"{m}:{ln} imports {t}.{n}" for n in names if n.startswith("_") and t != m]
        for node in ast.walk(ast.parse(p.read_text())):
            # module._name attribute access on an imported vcsumo module alias
            if isinstance(node, ast.Attribute) and node.attr.startswith("_") and not node.attr.startswith("__") \
                    and isinstance(node.value, ast.Name) and node.value.id.endswith("_mod"):
                bad.append(f"{m}:{node.lineno} uses {node.value.id}.{node.attr}")
    assert not bad, "\n".join(bad)


def test_modules_are_small():
    mods = _modules()
    big = {m: len(p.read_text().splitlines()) for m, p in mods.items()}
    bad = [f"{m}: {n} lines" for m, n in sorted(big.items()) if n > MAX_LINES and m not in LONG_MODULES]
    assert not bad, "\n".join(bad)
    stale = [m for m in LONG_MODULES if big.get(m, 0) <= MAX_LINES]
    assert not stale, f"no longer long, drop from LONG_MODULES: {stale}"
