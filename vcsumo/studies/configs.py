"""The options of every command as one typed model each: the command line and study files build the same one.

Each :class:`~vcsumo.config.CommandConfig` below lists a command's options as fields with their
bounds, unit (``json_schema_extra["unit"]``) and description.  ``vcsumo <command> --option`` and a
study file (``study: capacity`` ...) are validated by the same model, so a bound is checked once for
both; a problem is one line naming the option (``--block-length-m: -500: Input should be greater
than or equal to 100``) or the file and field.  The command-line options are generated from these
fields (:mod:`vcsumo.cli.options`); ``vcsumo study run FILE`` loads the same model and calls the
same function the command calls.

What a model cannot check alone — that the line, trains, controllers, assumption set and files it
names exist, that measuring points lie on the line — is checked by its :meth:`inputs`, which loads
them (before anything runs or is written), blaming the option or the study file's field.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import AfterValidator, BeforeValidator, Field, field_validator, model_validator

from vcsumo.config import CommandConfig, FieldProblem, is_file
from vcsumo.errors import InputError
from vcsumo.line import Line
from vcsumo.rolling_stock import RollingStock
from vcsumo.signalling.assumptions import AssumptionSet
from vcsumo.signalling.regimes import regime_names
from vcsumo.units import parse_clock


def _out_folder(v: str | None) -> str | None:
    if v is None:
        return v
    name = Path(v).name if v.strip() else ""
    if not name or name in (".", "..") or "\x00" in v:
        raise ValueError(f"'{v}' is not a results folder: name a new folder, e.g. results/my_study")
    from vcsumo.results import check_output_folder

    try:
        check_output_folder(Path(v))
    except InputError as exc:  # (as the option's own problem, before anything runs)
        raise ValueError(exc.message) from None
    return v


def _workers(v: Any) -> Any:
    try:
        below = v is not None and int(v) < 1
    except (TypeError, ValueError):
        return v  # not a number: the type check reports it
    if below:
        raise ValueError(f"{v}: must be 1 or more (1 runs in this process; default: the number of CPUs)")
    return v


def _clock(v: str | float | None) -> float | None:
    if v is None:
        return v
    try:
        return parse_clock(v if isinstance(v, (int, float)) or not v.replace(".", "", 1).isdigit() else float(v))
    except ValueError:
        raise ValueError(f"'{v}' is not a time (HH:MM[:SS] or s)") from None


WEEK_S = 7 * 86400.0
"""Longest simulated time, s (as timetables: one week)."""

LineSpec = Annotated[str, Field(min_length=1, description="Shipped line name, or path to a line.yaml", json_schema_extra={"path": True})]
LineOrNetwork = Annotated[str, Field(min_length=1, description="Shipped line or network name, or path to a line.yaml or network.yaml",
                                     json_schema_extra={"path": True})]
Out = Annotated[str | None, AfterValidator(_out_folder), Field(
    description="Results folder (default: a new folder under results/); in a study file relative to the current folder, without '..'")]
BlockLength = Annotated[float | None, Field(ge=100, le=50000, description="Block length overriding the line file's, m (100–50,000, as in line files)",
                                            json_schema_extra={"unit": "m"})]
Step = Annotated[float, Field(gt=0, le=2, json_schema_extra={"unit": "s"})]
Seed = Annotated[int, Field(ge=0, le=2**31 - 1, json_schema_extra={"unit": "1"},
                            description="Random seed of SUMO and of the VC channels (message delays and losses); the same seed gives the same results")]
Workers = Annotated[Annotated[int, Field(ge=1, le=512)] | None, BeforeValidator(_workers), Field(json_schema_extra={"unit": "processes"},
                                                                description="Parallel processes, 1–512 (1: in this process; default: the number of CPUs)")]
Scheduler = Annotated[str | None, Field(default=None, min_length=1, pattern=r"^(tcp|tls|inproc|ws|wss)://\S+$",
                                        description="Run the cases on a Dask cluster: address of its scheduler, tcp://HOST:PORT")]
Assumptions = Annotated[str | None, Field(min_length=1, description="Assumption set of the separation model: a shipped name or a .yaml path (default: etcs_typical)",
                                          json_schema_extra={"path": True})]
Controller = Annotated[str, Field(min_length=1, description="VC controller: mpc, cbc, cbf-mpc, cbf-cbc, cbf-cruise; NAME:PARAMS picks a parameter file")]
Km = Annotated[float, Field(ge=-100000.0, le=100000.0, json_schema_extra={"unit": "km"})]
Regime = Literal[regime_names()]  # type: ignore[valid-type]
"""A registered signalling regime (:mod:`vcsumo.signalling.regimes`)."""


class BuildNetworkConfig(CommandConfig):
    """``vcsumo build-network``."""

    line: LineOrNetwork
    block_length_m: BlockLength = None
    force: bool = Field(default=False, description="Rebuild even if the cached network is up to date")

    def inputs(self) -> Line:
        return load_line_spec(self, "line", network=True)


class RunConfig(CommandConfig):
    """``vcsumo run``: one timetable on a line under one regime."""

    line: LineOrNetwork
    timetable: str = Field(min_length=1, description="Timetable name (routes/<line>/<name>.yaml) or path", json_schema_extra={"path": True})
    regime: Regime = Field(description="Signalling regime")
    controller: Controller | None = Field(default=None, description="VC controller (vc only; default cbf-cbc): mpc, cbc, cbf-mpc, cbf-cbc, cbf-cruise; "
                                          "NAME:PARAMS picks a parameter file", json_schema_extra={"path": "spec"})
    channel: str | None = Field(default=None, min_length=1, description="Train-to-train channel settings, vc only: controllers/<name>.yaml or a path (default: channel)",
                                json_schema_extra={"path": True})
    step_length_s: Step | None = Field(default=None, description="SUMO step, s (0–2 s; default 0.5, 0.1 for vc)", json_schema_extra={"option": "--step-length", "unit": "s"})
    block_length_m: BlockLength = None
    assumptions: Assumptions = None
    seed: Seed = 42
    end_time: Annotated[float | None, Field(default=None, gt=0, le=WEEK_S, json_schema_extra={"unit": "s"},
                                            description="Stop the simulation at this time, HH:MM[:SS] or s (at most one week; default: when every train has arrived)")] = None
    sumo_fcd: bool = Field(default=False, description="Also write SUMO's fcd.xml (the same 1 s samples as trajectories.csv; off by default)")
    out: Out = None

    @field_validator("end_time", mode="before")
    @classmethod
    def _end_time(cls, v: Any) -> float | None:
        return _clock(v)

    @model_validator(mode="after")
    def _vc_only(self) -> "RunConfig":
        if self.regime != "vc":
            for f in ("controller", "channel"):
                if getattr(self, f) is not None:
                    raise FieldProblem(f, f"only the vc regime takes a controller and a channel (regime is {self.regime})")
        return self

    @property
    def step_s(self) -> float:
        """The SUMO step, s: as given, else 0.1 s for VC and 0.5 s for the others."""
        return self.step_length_s if self.step_length_s is not None else (0.1 if self.regime == "vc" else 0.5)

    def inputs(self) -> "RunInputs":
        from vcsumo.signalling.assumptions import load_assumptions
        from vcsumo.timetable import load_timetable

        line = load_line_spec(self, "line", network=True)
        with self.blame("timetable"):
            tt, tt_path = load_timetable(self.timetable, line)
        if self.controller:
            check_controller_spec(self, "controller", self.controller)
        if self.channel:
            from vcsumo.sim.vc_driver import load_channel

            with self.blame("channel"):
                load_channel(self.channel, None)
        with self.blame("assumptions"):
            aset = load_assumptions(self.assumptions)
        return RunInputs(line, tt, tt_path, aset)


@dataclass
class RunInputs:
    line: Line
    timetable: Any
    timetable_path: Path
    assumptions: AssumptionSet


class HeadwayConfig(CommandConfig):
    """``vcsumo study headway``: minimum headway by simulation vs blocking-time theory."""

    line: LineSpec
    regime: Literal["fbs", "mb", "both"] = Field(default="both", description="Signalling regime(s) studied")
    trains: list[Annotated[str, Field(min_length=1)]] = Field(default_factory=list, description="Train type(s), names or paths (default: the line's default_train)",
                                                                json_schema_extra={"option": "--train", "multiple": True, "path": True})
    points_km: list[Km] | None = Field(default=None, min_length=1, description="Measuring points, km of the line (default: the line file's)",
                                       json_schema_extra={"option": "--points", "unit": "km"})
    block_length_m: BlockLength = None
    step_length_s: Step = Field(default=0.5, description="SUMO step, s (0–2 s)", json_schema_extra={"option": "--step-length", "unit": "s"})
    trains_per_run: int = Field(default=2, ge=2, le=20, description="Trains released per probe (2–20; 2 = blocking-time pair)", json_schema_extra={"unit": "trains"})
    directions: list[Literal["up", "down"]] = Field(default_factory=lambda: ["up", "down"], min_length=1, description="Directions to study")
    assumptions: Assumptions = None
    out: Out = None

    def inputs(self) -> "StudyInputs":
        from vcsumo.signalling.assumptions import load_assumptions

        line = load_line_spec(self, "line")
        if self.trains:
            stocks = [load_train(self, f"trains[{i}]", t) for i, t in enumerate(self.trains)]
        else:
            stocks = [default_train(self, "trains", line)]
        lo, hi = line.data.km_start, line.data.km_end
        for i, k in enumerate(self.points_km or []):
            if not lo < k < hi:
                raise self.problem(f"points_km[{i}]", f"measuring point {k:g} km lies beyond the line {line.name} ({lo:g}–{hi:g} km)")
        with self.blame("assumptions"):
            aset = load_assumptions(self.assumptions)
        return StudyInputs(line, stocks, aset)


@dataclass
class StudyInputs:
    line: Line
    trains: list[RollingStock]
    assumptions: AssumptionSet


class CapacityConfig(CommandConfig):
    """``vcsumo study capacity``: line capacity under every regime, controller and convoy size."""

    line: LineSpec
    train: str | None = Field(default=None, min_length=1, description="Train type, name or path (default: the line's default_train)", json_schema_extra={"path": True})
    controllers: list[Controller] = Field(default_factory=lambda: ["cbc", "cbf-cbc"], description="VC controllers (NAME or NAME:PARAMS); empty: no VC cases",
                                          json_schema_extra={"path": "spec"})
    convoy_sizes: list[Annotated[int, Field(ge=1, le=8)]] = Field(default_factory=lambda: [1, 2, 3, 4], min_length=1,
                                                                  description="VC convoy sizes, trains (1–8)", json_schema_extra={"unit": "trains"})
    directions: list[Literal["up", "down"]] = Field(default_factory=lambda: ["up", "down"], min_length=1, description="Directions to study")
    patterns: list[Literal["non-stop", "all-stops"]] | None = Field(default=None, min_length=1,
                                                                    description="Stopping patterns (default: both where the line has intermediate stations)")
    block_length_m: BlockLength = None
    step_length_s: Step = Field(default=0.5, description="SUMO step for FBS and MB, s (0–2 s)", json_schema_extra={"option": "--step-length", "unit": "s"})
    vc_step_length_s: Step = Field(default=0.2, description="SUMO and controller step for VC, s (0–2 s)", json_schema_extra={"option": "--vc-step-length", "unit": "s"})
    fixed_time_s: float | None = Field(default=None, ge=0, le=120, json_schema_extra={"unit": "s"},
                                       description="ETCS fixed times (route setting + MA transmission + reaction), s (0–120 s; 10–20 s is typical), "
                                       "overriding the assumption set's: in the simulation and in the analytic headway")
    workers: Workers = None
    scheduler: Scheduler = None
    assumptions: Assumptions = None
    seed: Seed = 42
    out: Out = Field(default=None, description="Results folder (default: a new folder under results/); run again into the same folder to finish a stopped "
                     "study (only missing cases run); in a study file relative to the current folder, without '..'")

    def inputs(self) -> "StudyInputs":
        from vcsumo.signalling.assumptions import load_assumptions

        line = load_line_spec(self, "line")
        stock = load_train(self, "train", self.train) if self.train else default_train(self, "train", line)
        for i, c in enumerate(self.controllers):
            check_controller_spec(self, f"controllers[{i}]", c)
        with self.blame("assumptions"):
            aset = load_assumptions(self.assumptions)
        if self.fixed_time_s is not None:
            aset = aset.model_copy(update={"fixed_time_s": self.fixed_time_s})
        return StudyInputs(line, [stock], aset)


class BatchConfig(CommandConfig):
    """``vcsumo batch``: timetables × regimes × controllers × seeds with random primary delays."""

    line: LineOrNetwork
    timetables: str | None = Field(default=None, min_length=1, json_schema_extra={"path": "glob"},
                                   description="Timetables: comma-separated names, paths or glob patterns, e.g. 'routes/L/*.yaml' (default: every timetable of the line)")
    regimes: list[Regime] = Field(default_factory=lambda: list(regime_names()), min_length=1, description="Signalling regimes")
    seeds: int = Field(default=3, ge=1, le=1000, description="Seeds per timetable, regime and controller (1–1,000)", json_schema_extra={"unit": "seeds"})
    first_seed: int = Field(default=1, ge=0, le=2**31 - 1001, description="Seeds are first_seed, first_seed + 1, ...", json_schema_extra={"unit": "1"})
    controllers: list[Controller] | None = Field(default=None, min_length=1, description="VC controllers, vc only (default: cbf-cbc)",
                                                 json_schema_extra={"path": "spec"})
    delay_config: str | None = Field(default=None, min_length=1, json_schema_extra={"path": True},
                                     description="YAML file of primary delays (default: 30 % of trains exp(120 s) at origin, 10 % of stops exp(30 s))")
    workers: Workers = None
    scheduler: Scheduler = None
    step_length_s: Step = Field(default=0.5, description="SUMO step, s (0–2 s)", json_schema_extra={"option": "--step-length", "unit": "s"})
    block_length_m: BlockLength = None
    assumptions: Assumptions = None
    window_s: float = Field(default=3600.0, ge=60, le=86400, description="UIC 406 observation window, s (1 min–1 day): each section is judged in its busiest window of this length (the peak hour by default)", json_schema_extra={"unit": "s"})
    retry_failed: bool = Field(default=False, description="Run again the runs that failed in an earlier invocation")
    out: Out = Field(default=None, description="Batch folder (default: results/batch-<line>-<hash of line and delays>; the same command resumes there); "
                     "in a study file relative to the current folder, without '..'")

    @model_validator(mode="after")
    def _vc_controllers(self) -> "BatchConfig":
        if self.controllers is not None and "vc" not in self.regimes:
            raise FieldProblem("controllers", f"only the vc regime takes a controller (regimes are {', '.join(self.regimes)})")
        return self

    @classmethod
    def resolve_paths(cls, data: dict[str, Any], base: Path) -> dict[str, Any]:
        """Timetable names stay names; a path or glob pattern is relative to the study file, or, if
        nothing is there, to the data folder (``routes/<line>/*.yaml`` in a shipped study)."""
        import glob

        from vcsumo.config import looks_like_path
        from vcsumo.line import project_root

        out = super().resolve_paths({k: v for k, v in data.items() if k != "timetables"}, base)
        spec = data.get("timetables")
        if isinstance(spec, str):
            items = []
            for item in (x.strip() for x in spec.split(",")):
                if item and any(ch in item for ch in "*?[") and not Path(item).is_absolute():
                    item = str(base / item) if glob.glob(str(base / item)) else str(project_root() / item)
                elif item and looks_like_path(item) and not Path(item).is_absolute():
                    item = str(project_root() / item) if not (base / item).exists() and (project_root() / item).is_file() else str(base / item)
                items.append(item)
            spec = ",".join(items)
        if "timetables" in data:
            out["timetables"] = spec
        return out

    def inputs(self) -> "BatchInputs":
        from vcsumo.delays import load_delay_config
        from vcsumo.studies.batch import resolve_timetables

        line = load_line_spec(self, "line", network=True)
        with self.blame("timetables"):
            files = resolve_timetables(self.timetables, line)
        for i, c in enumerate(self.controllers or []):
            check_controller_spec(self, f"controllers[{i}]", c)
        delay_path = None
        if self.delay_config:
            if not is_file(self.delay_config):
                raise self.problem("delay_config", f"delay configuration '{self.delay_config}' not found")
            delay_path = Path(self.delay_config)
        delays = load_delay_config(delay_path)
        from vcsumo.signalling.assumptions import load_assumptions

        with self.blame("assumptions"):
            aset = load_assumptions(self.assumptions)
        return BatchInputs(line, files, delays, delay_path, list(range(self.first_seed, self.first_seed + self.seeds)), aset)


@dataclass
class BatchInputs:
    line: Line
    timetables: list[Path]
    delays: Any
    delay_config: Path | None
    seeds: list[int]
    assumptions: AssumptionSet


class StudyRunConfig(CommandConfig):
    """``vcsumo study run FILE``: the options besides the file."""

    out: Out = Field(default=None, description="Results folder (overrides the study file's out)")


# --------------------------------------------------------------------------------------------
# Loading what a configuration names, blaming its option or field


def load_line_spec(cfg: CommandConfig, field: str, network: bool = False) -> Line:
    """The line (``network``: or network of lines) named by ``field``."""
    from vcsumo.line import load_line
    from vcsumo.network_file import load_line_or_network

    with cfg.blame(field):
        return load_line_or_network(getattr(cfg, field)) if network else load_line(getattr(cfg, field))


def load_train(cfg: CommandConfig, field: str, spec: str) -> RollingStock:
    from vcsumo.rolling_stock import load_rolling_stock

    with cfg.blame(field):
        return load_rolling_stock(spec)


def default_train(cfg: CommandConfig, field: str, line: Line) -> RollingStock:
    """The line's ``default_train`` (an unknown one blames the line file, none at all the option)."""
    from vcsumo.rolling_stock import load_rolling_stock

    name = line.data.default_train
    if not name:
        raise cfg.problem(field, f"the line {line.name} names no default_train ({line.path}); name a train")
    try:
        return load_rolling_stock(name)
    except InputError as exc:
        if exc.path is None:
            raise InputError(line.path, "default_train", exc.message) from None
        raise


def check_controller_spec(cfg: CommandConfig, field: str, spec: str) -> None:
    """A VC controller name with its parameter files (resolved, not built)."""
    from vcsumo.control.registry import check_controller

    with cfg.blame(field):
        check_controller(spec, None)


CONFIGS: dict[str, type[CommandConfig]] = {"run": RunConfig, "build-network": BuildNetworkConfig, "study headway": HeadwayConfig,
                                           "study capacity": CapacityConfig, "batch": BatchConfig}
"""The command each configuration is the options of."""
