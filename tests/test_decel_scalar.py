"""The per-step (plain float) path of the relative-braking decelerations gives exactly the numbers
of the general (numpy) functions, for every shipped train, brake kind, speed and grade."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vcsumo.rolling_stock import load_rolling_stock, shipped_rolling_stock
from vcsumo.signalling.assumptions import load_assumptions
from vcsumo.signalling.separation import SeparationModel, guaranteed_decel, strongest_decel

STOCK = [load_rolling_stock(n) for n in shipped_rolling_stock()]
SETS = [load_assumptions(), load_assumptions().model_copy(update={"relative_braking": "service"})]


@settings(max_examples=300, deadline=None)
@given(f=st.sampled_from(STOCK), l=st.sampled_from(STOCK), a=st.sampled_from(SETS), v_f=st.floats(0.0, 120.0), v_l=st.floats(0.0, 120.0),
       g_f=st.floats(-0.035, 0.035), g_l=st.floats(-0.035, 0.035))
def test_float_path_equals_numpy_path(f, l, a, v_f, v_l, g_f, g_l):
    model = SeparationModel(a)
    kind = a.relative_braking
    try:
        expected = (guaranteed_decel(f, a, kind, v_f, g_f), strongest_decel(l, a, kind, v_l, g_l))
    except ValueError:
        with pytest.raises(ValueError):
            model.vc_decels(f, l, v_f, v_l, g_f, g_l)
        return
    assert model.vc_decels(f, l, v_f, v_l, g_f, g_l) == expected  # exactly: the same operations in the same order
