"""Controllers registered by name: the one place a controller name is parsed and a follower's stack built.

A controller name is a registered **family** (``mpc``, ``cbc``, ``cruise``) optionally composed
with a registered **supervisor** as ``<supervisor>-<family>`` (``cbf-mpc``, ``cbf-cbc``,
``cbf-cruise``), optionally followed by a parameter file after a colon: ``cbc:cbc_plf`` (a name in
``controllers/``) or ``cbf-cbc:my_cbc.yaml`` (a path; relative to the caller's ``base_dir``, e.g. a
study file's folder, else the working directory — :mod:`vcsumo.control.params`).  The supervisor
reads its own file (``controllers/cbf.yaml`` unless the caller names another).

:func:`build_follower_stack` turns a name and a :class:`StackContext` (the two trains, the step,
the route, the parameter specs) into a :class:`~vcsumo.control.stack.FollowerStack`: nominal
controller → supervisor → separation guard → fault stage.  The SUMO loop
(:mod:`vcsumo.sim.vc_driver`), the offline loop (:mod:`vcsumo.sim.offline`: the safety campaign,
the reproductions) and the tests all build their followers here, so what the campaign checks is
what the capacity studies run.

Adding a controller is one module (the controller class: ``make_step(obs) -> Command``, see
:mod:`vcsumo.control.base`) and one registry entry: a :class:`ControllerEntry` with its build
function (``(ctx, params) -> Nominal``), default parameter file, whether it reads predecessors'
plans and whether it may run without a supervisor — passed to :func:`register_controller` (the
shipped entries are at the end of this module).  Nothing else changes: every loop, study and
command-line option takes the new name.  A supervisor is added the same way with
:class:`SupervisorEntry` / :func:`register_supervisor` and composes with every family.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Callable

from pydantic import BaseModel

from vcsumo.control.faults import FaultStage
from vcsumo.control.guard import GuardConfig, SeparationGuard, default_guard
from vcsumo.control.params import resolve_params
from vcsumo.control.stack import FollowerStack, SampledController
from vcsumo.errors import InputError
from vcsumo.rolling_stock import RollingStock
from vcsumo.route_profile import RouteProfile
from vcsumo.signalling.assumptions import AssumptionSet, load_assumptions
from vcsumo.signalling.separation import SeparationModel

ParamSpec = str | Path | BaseModel | None
"""A parameter file name (``controllers/``), a path, an already loaded settings object, or None (the default)."""


@dataclass(frozen=True)
class StackContext:
    """What a builder may use to make one follower's stack."""

    ego: RollingStock
    predecessor: RollingStock
    step_s: float
    """Control (and loop) step, s."""
    profile: RouteProfile | None = None
    """The follower's route (None: not known when the stack is built)."""
    params: ParamSpec = None
    """The nominal controller's parameters (None: the name's ``:PARAMS`` or the family default)."""
    supervisor_params: ParamSpec = None
    """The supervisor's parameters (None: its default, ``controllers/cbf.yaml``); the cruise family reads it too."""
    assumptions: AssumptionSet | None = None
    """The separation model's assumption set the guard (and the supervisor's distance) work under
    (None: the shipped default)."""
    guard: GuardConfig | None | bool = True
    """The separation guard's settings: True (``controllers/guard.yaml``: :func:`~vcsumo.control.guard.default_guard`), a :class:`GuardConfig`, or
    False/None — no guard (only for a paper's own architecture, e.g. the reproductions)."""
    base_dir: Path | None = None
    """Folder relative parameter paths are taken from (e.g. a study file's), else the working directory."""
    field: str | None = "--controller"
    """Field named in errors (``--controller``, ``controllers[1]``)."""
    ego_id: str | None = None
    predecessor_id: str | None = None
    control_period_s: float | None = None
    """Period of the nominal controller (the ATO cycle; None: every step)."""
    message_age_s: float | None = None
    """The age of the predecessor's newest message the channel keeps
    (:meth:`~vcsumo.control.channel.ChannelConfig.age_budget_s`), s: a certified spacing reference
    (cbc) budgets the larger of it and the assumption set's bound (None: the set's bound); the
    supervisor and the guard act on the true age whatever it is."""
    position_error_m: float = 0.0
    """Bound of the odometry error the supervisor and the guard must allow for (Felez eq. 9), m."""
    record: bool = True
    """Let the supervisor keep its per-step history."""
    recovery_s: float = 1.0
    """The fault stage's latch, s."""
    supervisor_gap_m: float | None = None
    """The minimum gap the stack's supervisor protects (its d), m, set by :func:`build_follower_stack`
    for a supervised family (None: no supervisor): a nominal controller with a gap constraint of its
    own keeps it there rather than commanding traction into the supervisor's barrier."""
    reuse: dict | None = None
    """A cache owned by the caller in which builders may keep expensive objects between builds
    that the caller declares interchangeable (same route and convoy slot, used one at a time)."""

    @property
    def period_s(self) -> float:
        return self.control_period_s or self.step_s


@dataclass(frozen=True)
class Nominal:
    """What a family's build function returns."""

    controller: Any
    d_min_m: float
    coupled_gap: Callable[..., float]
    """The controller's own front-to-rear spacing at a common speed v (and, where its reference is on
    the route, with the follower's front at ``position_m``), m."""


@dataclass(frozen=True)
class ControllerEntry:
    """A registered nominal controller family."""

    name: str
    build: Callable[[StackContext, Any], Nominal]
    """``(ctx, params) -> Nominal``; ``params`` is the resolved Path of the parameter file or the
    settings object the caller gave."""
    default_params: str | None
    """Name of its default parameter file in ``controllers/`` (None: it needs none; ``build`` then
    gets None unless a ``:PARAMS`` file is named)."""
    uses_plans: bool
    """Predecessors must broadcast their predicted trajectories (SH predictor, RLP)."""
    standalone: bool = True
    """May run without a supervisor (False: only as ``<supervisor>-<name>``)."""
    doc: str = ""


@dataclass(frozen=True)
class SupervisorEntry:
    """A registered supervisor (safety filter) composing as ``<name>-<family>``."""

    name: str
    build: Callable[[StackContext, Any], tuple[Any, float]]
    """``(ctx, params) -> (supervisor, d_min_m)``: the filter and the minimum safe gap it protects."""
    default_params: str
    doc: str = ""


CONTROLLERS: dict[str, ControllerEntry] = {}
"""Nominal controller families by name (registration order)."""
SUPERVISORS: dict[str, SupervisorEntry] = {}
"""Supervisors by name."""


def register_controller(entry: ControllerEntry) -> ControllerEntry:
    if "-" in entry.name or ":" in entry.name:
        raise ValueError(f"controller name '{entry.name}' may not contain '-' or ':'")
    CONTROLLERS[entry.name] = entry
    return entry


def register_supervisor(entry: SupervisorEntry) -> SupervisorEntry:
    if "-" in entry.name or ":" in entry.name:
        raise ValueError(f"supervisor name '{entry.name}' may not contain '-' or ':'")
    SUPERVISORS[entry.name] = entry
    return entry


def controller_names() -> tuple[str, ...]:
    """Every valid controller name: the standalone families, then each supervisor with every family."""
    plain = [n for n, e in CONTROLLERS.items() if e.standalone]
    supervised = [f"{s}-{n}" for s in SUPERVISORS for n in CONTROLLERS]
    return tuple(plain + supervised)


@dataclass(frozen=True)
class ControllerSpec:
    """A parsed controller name."""

    name: str
    """``cbf-cbc``."""
    family: str
    """``cbc``."""
    supervisor: str | None
    """``cbf`` or None."""
    params: str | None
    """The parameter spec after the colon, or None."""

    @property
    def entry(self) -> ControllerEntry:
        return CONTROLLERS[self.family]

    @property
    def uses_plans(self) -> bool:
        return self.entry.uses_plans


def controller_spec(spec: str, field: str | None = "--controller") -> ControllerSpec:
    """Parse ``NAME[:PARAMS]`` (InputError naming ``field`` for an unknown name)."""
    name, _, params = str(spec).partition(":")
    sup, _, fam = name.partition("-") if "-" in name else (None, None, name)
    ok = (sup is None and fam in CONTROLLERS and CONTROLLERS[fam].standalone) or (sup in SUPERVISORS and fam in CONTROLLERS)
    if not ok:
        raise InputError(None, field, f"unknown controller '{name}' (choose from {', '.join(controller_names())}; NAME:PARAMS picks a parameter file)")
    return ControllerSpec(name, fam, sup, params or None)


def parse_controller(spec: str, field: str | None = "--controller") -> tuple[str, str | None]:
    """'cbf-cbc:cbc_plf' -> ('cbf-cbc', 'cbc_plf')."""
    s = controller_spec(spec, field)
    return s.name, s.params


def check_controller(spec: str, field: str | None = "--controller", base_dir: Path | None = None, supervisor_params: ParamSpec = None) -> ControllerSpec:
    """Parse a name and resolve its parameter files (errors name ``field``); nothing is built."""
    s = controller_spec(spec, field)
    if s.params is not None or s.entry.default_params is not None:
        resolve_params(s.params, s.entry.default_params, field, base_dir)
    if s.supervisor is not None and not isinstance(supervisor_params, BaseModel):
        resolve_params(supervisor_params, SUPERVISORS[s.supervisor].default_params, field, base_dir)
    return s


def _params(spec: ParamSpec, default: str | None, ctx: StackContext) -> Any:
    """A settings object as given, or the resolved parameter file (None: no file and no default)."""
    if isinstance(spec, BaseModel):
        return spec
    if default is None and (spec is None or not str(spec).strip()):
        return None
    return resolve_params(spec, default, ctx.field, ctx.base_dir)


def build_follower_stack(spec: str, ctx: StackContext) -> FollowerStack:
    """The follower's stack for controller ``spec`` (see the module doc).

    The nominal controller's parameters are ``ctx.params`` if given, else the spec's ``:PARAMS``,
    else the family default; the supervisor's ``ctx.supervisor_params`` or its default."""
    s = controller_spec(spec, ctx.field)
    entry = s.entry
    nominal_params = _params(ctx.params if ctx.params is not None else s.params, entry.default_params, ctx)
    supervisor, files = None, {}
    if s.supervisor is not None:  # built first: the nominal controller is told the gap it protects
        sup_entry = SUPERVISORS[s.supervisor]
        sup_params = _params(ctx.supervisor_params, sup_entry.default_params, ctx)
        supervisor, d_sup = sup_entry.build(ctx, sup_params)
        ctx = replace(ctx, supervisor_gap_m=d_sup)
        files["supervisor"] = str(sup_params) if isinstance(sup_params, Path) else "(given)"
    built = entry.build(ctx, nominal_params)
    files = {"nominal": str(nominal_params) if isinstance(nominal_params, Path) else ("(given)" if nominal_params is not None else ""), **files}
    d_min = built.d_min_m if supervisor is None else max(built.d_min_m, ctx.supervisor_gap_m)
    controller = built.controller
    if ctx.control_period_s is not None and abs(ctx.control_period_s - ctx.step_s) > 1e-9:
        controller = SampledController(controller, ctx.control_period_s)
    guard = None
    if ctx.guard is not None and ctx.guard is not False:
        model = SeparationModel(ctx.assumptions or load_assumptions())
        guard = SeparationGuard(ctx.ego, ctx.predecessor, d_min, ctx.guard if isinstance(ctx.guard, GuardConfig) else default_guard(), model,
                                ctx.position_error_m)
    stage = FaultStage(controller, ctx.ego.params(), supervisor, ctx.ego_id, ctx.recovery_s, guard=guard)
    return FollowerStack(s.name, built.controller, supervisor, guard, stage, d_min, built.coupled_gap, entry.uses_plans, files)


# -------------------------------------------------------------------------------------------
# The shipped controllers


def _build_cbc(ctx: StackContext, params) -> Nominal:
    from vcsumo.control.consensus import CbcParams, ConsensusController, load_cbc_params

    prm = params if isinstance(params, CbcParams) else load_cbc_params(params)
    ctrl = ConsensusController(prm)
    if not prm.gap.certified:
        return Nominal(ctrl, prm.gap.d_min_m, lambda v, position_m=None: prm.gap.gap_m(v, v))  # eq. 3.1 + constant time headway
    from vcsumo.control.gap_reference import SeparationGap

    model = SeparationModel(ctx.assumptions or load_assumptions())
    ctrl.default_gap = ref = SeparationGap(model, ctx.ego, ctx.predecessor, ctx.profile, 1.5 * ctx.step_s, prm.gap.buffer_m, ctx.message_age_s)
    return Nominal(ctrl, prm.gap.d_min_m, lambda v, position_m=None: ref.gap_m(v, v, position_m))  # the certified spacing (on the route's gradients)


def _build_mpc(ctx: StackContext, params) -> Nominal:
    """Felez et al.'s follower NMPC (eq. 12) solved every control period over the horizon
    N_p·step_s it has at the loop step; its braking assumption a^f (12m) capped at the train's
    nominal service deceleration.  With ``ctx.reuse`` one instance per route and slot is kept (its
    DP profile and terminal set, eq. 10/12m, are computed once) and reset between builds."""
    from vcsumo.control.mpc import FollowerMPC, MPCSettings, load_mpc_settings

    settings = params if isinstance(params, MPCSettings) else load_mpc_settings(params)
    period = ctx.period_s
    update: dict = {}
    a_f = min(settings.a_follower_mps2, ctx.ego.service_brake_decel_mps2)
    if a_f != settings.a_follower_mps2:
        update["a_follower_mps2"] = a_f
    if ctx.supervisor_gap_m is not None and ctx.supervisor_gap_m > settings.d_min_m:
        # under a supervisor, d_min (12f/12l, 12m) is the gap the supervisor protects and d_des keeps
        # its margin above it: with Felez's 4 m / 10 m the NMPC commanded traction into its CBF's
        # barrier for ever behind a stopped leader (an emergency override every other step)
        shift = ctx.supervisor_gap_m - settings.d_min_m
        update["d0_m"] = settings.d0_m + shift
        update["d_des_m"] = settings.d_des_m + shift
    if abs(period - ctx.step_s) > 1e-9:
        update["horizon_steps"] = max(5, int(round(settings.horizon_steps * ctx.step_s / period)))
    if abs(settings.step_s - period) > 1e-9:
        update["step_s"] = period
    if update:
        settings = settings.model_copy(update=update)
    end = ctx.profile.length_m if ctx.profile is not None else None
    p = ctx.ego.params()
    ctrl = None
    if ctx.reuse is not None:  # one instance per route, settings and follower (ego id), reset between builds
        route_key = ("mpc-route", settings.model_dump_json(), p, end, id(ctx.profile))
        key = route_key[1:] + (ctx.ego_id,)
        cached = ctx.reuse.get(key)
        if cached is not None and cached[0] is ctx.profile:
            ctrl = cached[1]
            ctrl.reset()
    if ctrl is None:
        ctrl = FollowerMPC(p, settings, route_end_m=end)
        if ctx.reuse is not None:
            donor = ctx.reuse.get(route_key)
            if donor is not None and donor[0] is ctx.profile:
                ctrl.share_route_data(donor[1])  # the DP profile and terminal set of this route, computed once
            elif ctx.profile is not None:
                ctrl.route_data(ctx.profile)
                ctx.reuse[route_key] = (ctx.profile, ctrl)
            ctx.reuse[key] = (ctx.profile, ctrl)
    s = ctrl.settings

    def coupled(v: float, position_m: float | None = None) -> float:  # the relative braking distance of constraint 12m, at least d_des
        rel = v * v / (2.0 * s.a_follower_mps2) - v * v / (2.0 * s.a_leader_mps2)
        return max(s.d_des_m, s.d_min_m + max(rel, 0.0))

    return Nominal(ctrl, s.d_min_m, coupled)


def _build_cruise(ctx: StackContext, params) -> Nominal:
    """Terlizzi et al.'s switched cruise controller (Algorithm 4–5); it reads the CBF's parameters too."""
    from vcsumo.control.cbf import CBFConfig, load_cbf_config, model_safety_distance_m
    from vcsumo.control.cruise import CruiseConfig, SwitchedCruiseController, load_cruise_config

    cfg = params if isinstance(params, CruiseConfig) else load_cruise_config(params)
    cbf = _params(ctx.supervisor_params, "cbf", ctx)
    cbf_cfg = cbf if isinstance(cbf, CBFConfig) else load_cbf_config(cbf)
    ctrl = SwitchedCruiseController(ctx.predecessor, ctx.ego, cfg, cbf_cfg, leader_id=ctx.predecessor_id)
    d = cbf_cfg.safety_distance_m if cbf_cfg.distance == "fixed" else model_safety_distance_m(SeparationModel(ctx.assumptions or load_assumptions()), cbf_cfg)
    return Nominal(ctrl, d, lambda v, position_m=None: d)


def _build_cbf(ctx: StackContext, params) -> tuple[Any, float]:
    """Terlizzi et al.'s CBF supervisor (Algorithm 1–3, eq. 15, 18) under the context's assumption set
    (``distance: model``: the barrier on the separation model); it allows for the odometry error bound
    of the context.  The minimum safe gap it protects is its d."""
    from vcsumo.control.cbf import CBFConfig, CBFSupervisor, load_cbf_config, model_leader_braking

    cfg = params if isinstance(params, CBFConfig) else load_cbf_config(params)
    if ctx.position_error_m > cfg.position_error_m:  # the supervisor knows the bound of the odometry error (Felez eq. 9)
        cfg = cfg.model_copy(update={"position_error_m": ctx.position_error_m})
    model = SeparationModel(ctx.assumptions or load_assumptions())
    if cfg.distance == "model":
        model_leader_braking(model, cfg)  # a leader brake weaker than the set's: refused before the run starts
    sup = CBFSupervisor(ctx.predecessor, ctx.ego, cfg, leader_id=ctx.predecessor_id, record=ctx.record, model=model)
    return sup, sup.safety_distance_m


register_controller(ControllerEntry("mpc", _build_mpc, "mpc", uses_plans=True, doc="Follower NMPC of Felez et al. (2019), eq. 12 with the SH predictor"))
register_controller(ControllerEntry("cbc", _build_cbc, "cbc", uses_plans=False, doc="Consensus-based control (Wu et al. survey eq. 3.1, 4.x)"))
register_controller(ControllerEntry("cruise", _build_cruise, "cruise_terlizzi2024", uses_plans=True, standalone=False,
                                    doc="Switched cruise controller of Terlizzi et al. (2024), Algorithm 4–5 (with its CBF only)"))
register_supervisor(SupervisorEntry("cbf", _build_cbf, "cbf", doc="CBF safety supervisor of Terlizzi et al. (2024), Algorithm 1–3"))


__all__ = [
    "CONTROLLERS", "SUPERVISORS", "ControllerEntry", "SupervisorEntry", "StackContext", "Nominal", "ControllerSpec", "FollowerStack",
    "register_controller", "register_supervisor", "controller_names", "controller_spec", "parse_controller", "check_controller", "build_follower_stack",
]
