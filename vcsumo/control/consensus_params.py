"""Settings of the consensus-based convoy controller (``controllers/cbc*.yaml``): the law (eq. 4.1–4.5,
4.10, 4.11), the T2T topology, the gap reference and the gains (Wu et al. survey §IV.A; the law is
described in :mod:`vcsumo.control.consensus`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

from pydantic import Field, model_validator

from vcsumo.config import StrictModel, load_model
from vcsumo.control.gap_reference import SteadyGap
from vcsumo.control.topology_graph import TopologyName


class LiuParams(StrictModel):
    """Gains of eq. 4.10 (Liu [76])."""

    k1_per_s2: float = Field(default=0.06, gt=0, description="Gain on the current spacing error, 1/s²")
    k2_mps2: float = Field(default=0.5, ge=0, description="Gain of the delayed-distance term, m/s²")
    k3: float | None = Field(default=None, description="Offset (none: chosen so the bracket vanishes at the reference gap)")
    k4: float = Field(default=1.0, description="Amplitude of the tanh term, -")
    k5_per_m: float = Field(default=0.02, gt=0, description="Slope of the tanh term, 1/m")
    k6: float | None = Field(default=None, description="Shift of the tanh term, - (none: k5·d^de, centred on the reference)")
    k_rel_speed_per_s: float = Field(default=0.6, ge=0, description="Relative-speed damping, 1/s (0 in the survey's eq. 4.10)")


class ZhouParams(StrictModel):
    """Gains of eq. 4.11 (Zhou et al. [77])."""

    k1_mps2: float = Field(default=0.6, gt=0, description="Spacing-error gain, m/s²")
    k2_mps2: float = Field(default=0.6, gt=0, description="Speed-error gain, m/s²")
    k3_mps2: float = Field(default=0.002, ge=0, description="Speed-limit barrier gain, m/s²")
    spacing_scale_m: float = Field(default=15.0, gt=0, description="ℓ: e^sp/ℓ inside tanh, m")
    speed_scale_mps: float = Field(default=1.0, gt=0, description="ν: e^sv/ν inside tanh, m/s")


class CbcParams(StrictModel):
    """Consensus-based controller settings (``controllers/cbc.yaml``)."""

    law: Literal["consensus", "liu_tanh", "zhou_tanh"] = Field(default="consensus", description="eq. 4.1–4.5 (consensus), 4.10 or 4.11")
    topology: TopologyName = Field(default="PF", description="T2T communication topology (PF, PLF, BD, BDL, TPF)")
    gap: SteadyGap = Field(default_factory=SteadyGap, description="Steady gap reference (eq. 3.1 + time headway)")
    k_pos_per_s2: float = Field(default=0.04, gt=0, description="k_x: position-disagreement gain, 1/s²")
    k_vel_per_s: float = Field(default=0.8, ge=0, description="k_v: speed-disagreement gain, 1/s")
    k_acc: float = Field(default=0.5, ge=0, description="k_a: acceleration-disagreement gain (third-order eq. 4.1), -")
    k_ref_vel_per_s: float = Field(default=0.0, ge=0, description="k_v0: damping towards the reference speed v_0 (eq. 4.3 k2, eq. 4.5 k1), 1/s")
    k_own_acc: float = Field(default=0.0, ge=0, description="k_a0: own-acceleration damping (eq. 4.3 k3), -")
    accel_feedforward: float = Field(default=0.5, ge=0, le=1, description="c_ff: weight of the neighbours' acceleration feed-forward, -")
    normalize: bool = Field(default=True, description="Divide by Σ a_ij (eq. 4.3); false: plain eq. 4.1")
    delay_compensation: Literal["none", "reference", "sender"] = Field(
        default="reference", description="Add τ_ij·v_0 (reference, eq. 4.3), τ_ij·v_j (sender) or nothing to delayed positions"
    )
    link_bound_mps2: float | None = Field(default=None, gt=0, le=10, description="Δ of eq. 4.4: per-link saturation, m/s², up to 10 (none: linear)")
    max_message_age_s: float = Field(default=5.0, gt=0, le=600, description="Older messages are ignored (link treated as lost), s (at most 600)")
    speed_limit_gain_per_s: float | None = Field(default=0.5, gt=0, description="u ≤ k·(v_lim − v) keeps the line/train speed limit (none: off), 1/s")
    leader_speed_gain_per_s: float = Field(default=0.3, gt=0, description="P gain when this controller drives a convoy leader, 1/s")
    liu: LiuParams = Field(default_factory=LiuParams)
    zhou: ZhouParams = Field(default_factory=ZhouParams)

    @model_validator(mode="after")
    def _pf_only(self) -> "CbcParams":
        if self.law != "consensus" and self.topology != "PF":
            raise ValueError(f"law '{self.law}' is a predecessor-follower law (eq. 4.10/4.11): topology must be PF")
        return self


def load_cbc_params(spec: str | Path = "cbc", field: str | None = "controller", base_dir: str | Path | None = None) -> CbcParams:
    """Load CBC settings by name (``cbc`` → ``controllers/cbc.yaml``) or by path to a YAML file
    (resolved by :func:`vcsumo.control.params.resolve_params`; errors name ``field``)."""
    from vcsumo.control.params import resolve_params

    return load_model(CbcParams, resolve_params(spec, "cbc", field, base_dir))


def cbc_params_for(topology: str, base: CbcParams | None = None, **changes: Any) -> CbcParams:
    """A copy of ``base`` (default settings) with another topology and field changes, re-validated."""
    data = (base or CbcParams()).model_dump()
    data.update(changes)
    data["topology"] = topology
    return CbcParams.model_validate(data)
