"""Study files: ``studies/*.yaml`` run with ``vcsumo study run FILE``.

A study file names its kind (``study: capacity | headway | batch | junction | safety | tradeoff``), a title and
notes, and the options of the matching command as fields of the command's own configuration model
(:mod:`vcsumo.studies.configs`): the same names, units and bounds as the command line.  It is
validated strictly (unknown keys are errors; every problem is listed), the names and files it refers
to are checked, and then the same function the command calls runs it, recording the study file among
the results' inputs.  Paths in a study file (line, trains, timetables, assumption sets, delay
configurations, controller parameter files) are relative to the file; its ``out`` is relative to the
current folder and may not leave it.

``junction``, ``safety`` and ``tradeoff`` are not yet built from one configuration model: their file models are
here and :func:`run_study` hands their values to the command (``click.Context.invoke``).  Converting
one is: give its Config the ``CommandConfig`` base and option names, generate its command with
:func:`vcsumo.cli.options.config_command`, and list it in :data:`KINDS` with its function.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, Callable, Literal

import click
from pydantic import Field, field_validator

from vcsumo.config import CommandConfig, StrictModel, read_yaml
from vcsumo.errors import InputError
from vcsumo.studies.configs import BatchConfig, CapacityConfig, HeadwayConfig, Out, check_controller_spec, load_line_spec, load_train
from vcsumo.studies.safety import SafetyCampaign
from vcsumo.studies.tradeoff import TradeoffConfig


class StudyFile(StrictModel):
    """The fields every study file has besides its command's options."""

    title: str = Field(default="", description="What the study is about")
    notes: str = Field(default="", description="Free text: assumptions, sources")

    @field_validator("out", mode="before", check_fields=False)
    @classmethod
    def _out_stays_here(cls, v: Any) -> Any:
        if not isinstance(v, str):
            return v  # not text: the field's type check reports it
        p = Path(v)
        if not v.strip() or p.is_absolute() or ".." in p.parts or v.startswith("~") or "\\" in v or "\x00" in v:
            raise ValueError(f"'{v}' must be a relative folder without '..' (a study file may not write outside the current folder; use --out for that)")
        return v


class CapacityStudy(StudyFile, CapacityConfig):
    study: Literal["capacity"]


class HeadwayStudy(StudyFile, HeadwayConfig):
    study: Literal["headway"]


class BatchStudy(StudyFile, BatchConfig):
    study: Literal["batch"]


BlockLength = Annotated[float, Field(ge=100, le=50000, description="Block length, m (100 m–50 km, as in line files)")]
Step = Annotated[float, Field(gt=0, le=2, description="Simulation step, s (at most 2 s)")]


class JunctionStudy(StudyFile, CommandConfig):
    """``vcsumo study junction`` (its command is not yet generated from this model)."""

    study: Literal["junction"]
    line: str = Field(min_length=1, description="Shipped line name or path to a line.yaml", json_schema_extra={"path": True})
    train: str | None = Field(default=None, description="Train type (default: the line's default_train)", json_schema_extra={"path": True})
    controllers: list[str] = Field(default_factory=lambda: ["cbc", "cbf-cbc"], json_schema_extra={"path": "spec"})
    junction: str | None = Field(default=None, description="Branch id(s), comma-separated, or 'all' (default: chosen from the line file)")
    first: Literal["main", "branch", "both"] = "both"
    junction_signal: Literal["sumo", "braking-curve", "both"] = "braking-curve"
    directions: list[Literal["up", "down"]] = Field(default_factory=lambda: ["up", "down"], min_length=1)
    offsets_s: list[Annotated[float, Field(ge=-3600, le=3600)]] | None = Field(default=None, min_length=1, description="Release offsets between the services, s (within ±1 h)")
    approach_m: float = Field(default=12000.0, gt=0, le=200000, description="Main-line release distance before the first junction, m (up to 200 km)")
    window_m: float = Field(default=5000.0, gt=0, le=50000, description="Measuring window around the junction, m (up to 50 km)")
    block_length_m: BlockLength | None = None
    step_length_s: Step = 0.5
    vc_step_length_s: Step = 0.2
    assumptions: str | None = Field(default=None, description="Assumption set of the separation model (shipped name or path; default etcs_typical)",
                                    json_schema_extra={"path": True})
    seed: int = Field(default=42, ge=0, le=2**31 - 1, description="Random seed (not negative)")
    out: Out = None

    def inputs(self) -> None:
        from vcsumo.signalling.assumptions import load_assumptions

        line = load_line_spec(self, "line")
        with self.blame("assumptions"):
            load_assumptions(self.assumptions)
        if self.train:
            load_train(self, "train", self.train)
        for i, c in enumerate(self.controllers):
            check_controller_spec(self, f"controllers[{i}]", c)
        if self.junction:
            from vcsumo.studies.junction import resolve_junctions

            resolve_junctions(line, self.junction, self.source, "junction")

    def command_values(self) -> dict[str, Any]:
        """The values of ``vcsumo study junction``'s parameters."""
        values = dict(line_spec=self.line, junctions=self.junction, train=self.train, controllers=",".join(self.controllers), first=self.first,
                      variants=self.junction_signal, directions=",".join(self.directions), approach_m=self.approach_m, window_m=self.window_m,
                      block_length_m=self.block_length_m, step_length=self.step_length_s, vc_step_length=self.vc_step_length_s, seed=self.seed,
                      assumptions=self.assumptions, out=self.out_path)
        if self.offsets_s:
            values["offsets"] = ",".join(f"{o:g}" for o in self.offsets_s)
        return values


class SafetyStudy(StudyFile, SafetyCampaign, CommandConfig):
    """``vcsumo study safety``: the campaign's parameters (:class:`~vcsumo.studies.safety.SafetyCampaign`) and workers."""

    study: Literal["safety"]
    lines: list[str] = Field(default_factory=lambda: ["firenze_bologna", "milano_bologna", "hcmc_line1"], min_length=1,
                             description="Shipped line names or line.yaml paths the scenarios are drawn on", json_schema_extra={"path": True})
    rolling_stock: list[str] = Field(default_factory=lambda: ["etr1000", "regional_emu160", "hcmc_l1"], min_length=1,
                                     description="Rolling stock a heterogeneous convoy's trains are drawn from (names or paths)", json_schema_extra={"path": True})
    assumptions: str | None = Field(default=None, description="Assumption set of the separation model (shipped name or path; default etcs_typical)",
                                    json_schema_extra={"path": True})
    cbf_config: str | None = Field(default=None, description="CBF parameter file (default controllers/cbf.yaml)", json_schema_extra={"path": True})
    workers: int | None = Field(default=None, ge=1, le=512, description="Parallel processes, 1–512 (default: number of CPUs)")
    out: Out = None

    def inputs(self) -> None:
        from vcsumo.line import load_line

        from vcsumo.signalling.assumptions import load_assumptions

        for i, spec in enumerate(self.lines):
            with self.blame(f"lines[{i}]"):
                load_line(spec)
        for i, spec in enumerate(self.controllers):
            check_controller_spec(self, f"controllers[{i}]", spec)
        for i, spec in enumerate(self.rolling_stock):
            load_train(self, f"rolling_stock[{i}]", spec)
        if self.assumptions:
            with self.blame("assumptions"):
                load_assumptions(self.assumptions)
        if self.cbf_config:
            check_controller_spec(self, "cbf_config", f"cbf-cbc:{self.cbf_config}")

    def command_values(self) -> dict[str, Any]:
        """The values of ``vcsumo study safety``'s parameters."""
        names = ["scenarios", "seed", "step_s", "control_period_s", "followers_max", "channel_period_s", "loss_max", "delay_max_s", "mean_extra_max_s",
                 "outage_probability", "outage_max_s", "corner_probability", "position_error_max_m", "max_duration_s", "cbf_config", "workers", "loop", "heterogeneous_probability", "assumptions"]
        return dict({n: getattr(self, n) for n in names}, lines=",".join(self.lines), controllers=",".join(self.controllers), kinds=",".join(self.kinds),
                    rolling_stock=",".join(self.rolling_stock), scheduler=None, out=self.out_path)


class TradeoffStudy(StudyFile, TradeoffConfig, CommandConfig):
    """``vcsumo study tradeoff``: the study's options (:class:`~vcsumo.studies.tradeoff.TradeoffConfig`)."""

    study: Literal["tradeoff"]
    line: str = Field(min_length=1, description="Shipped line name or path to a line.yaml", json_schema_extra={"path": True})
    train: str | None = Field(default=None, description="Train type (default: the line's default_train)", json_schema_extra={"path": True})
    assumptions: str | None = Field(default=None, description="Base assumption set: shipped name or .yaml path (default: etcs_typical)",
                                    json_schema_extra={"path": True})
    out: Out = None

    def inputs(self) -> None:
        load_line_spec(self, "line")
        if self.train:
            load_train(self, "train", self.train)
        check_controller_spec(self, "controller", self.controller)

    def command_values(self) -> dict[str, Any]:
        """The values of ``vcsumo study tradeoff``'s parameters."""
        def floats(v: list[float]) -> str:
            return ",".join(f"{x:g}" for x in v)

        return dict(line_spec=self.line, train=self.train, convoy_sizes=",".join(map(str, self.convoy_sizes)), delays=floats(self.delays_s),
                    uncertainties=floats(self.uncertainties), position_errors=floats(self.position_errors_m), grid=self.grid,
                    assumptions=self.assumptions, pattern=self.pattern, direction=self.direction, simulate_check=self.simulate_check,
                    controller=self.controller, block_length_m=self.block_length_m, step_length=self.step_length_s,
                    vc_step_length=self.vc_step_length_s, seed=self.seed, out=self.out_path)


KINDS: dict[str, type[CommandConfig]] = {"capacity": CapacityStudy, "headway": HeadwayStudy, "batch": BatchStudy, "junction": JunctionStudy,
                                         "safety": SafetyStudy, "tradeoff": TradeoffStudy}
"""Study kinds (``study:``) and their file models."""


def load_study(path: str | Path) -> CommandConfig:
    """Read and validate a study file (every problem named with its field), then check the line,
    trains, controllers and files it names: nothing runs before they all exist."""
    path = Path(path)
    data = read_yaml(path)
    kinds = ", ".join(KINDS)
    if data is None:
        raise InputError(path, None, f"the file is empty (expected a mapping with study: {kinds})")
    if not isinstance(data, dict):
        raise InputError(path, None, f"expected a mapping with study: {kinds}, got a {type(data).__name__}")
    if "study" not in data:
        raise InputError(path, "study", f"required field is missing ({kinds})")
    kind = data["study"]
    if not isinstance(kind, str) or kind not in KINDS:
        raise InputError(path, "study", f"unknown study '{kind}' (choose {kinds})")
    study = KINDS[kind].from_file(data, path)
    study.inputs()  # type: ignore[attr-defined]
    return study


def shipped_or_path(spec: Path) -> Path:
    """A study file path, or the name of a shipped study (``studies/<name>.yaml`` of the data folder)."""
    from vcsumo.line import project_root

    shipped = project_root() / "studies" / f"{spec}.yaml"
    if not spec.exists() and spec.suffix not in (".yaml", ".yml"):
        if shipped.is_file():
            return shipped
        # a name that is neither (before: "error: nosuch: file not found", not saying names are looked up or which exist)
        names = sorted(p.stem for p in (project_root() / "studies").glob("*.yaml"))
        raise InputError(None, "STUDY_FILE", f"unknown study '{spec}' (shipped: {', '.join(names) or 'none'}; or a path to a .yaml file)")
    return spec


def run_study(study: CommandConfig, out: Path | None = None) -> None:
    """Run a loaded study file with the function its command calls (``out`` overrides the file's)."""
    from vcsumo.cli import batch, commands
    from vcsumo.results import recording

    if out is not None:
        study = study.model_copy(update={"out": str(out)})
    functions: dict[type, Callable[[Any], None]] = {CapacityStudy: commands.capacity, HeadwayStudy: commands.headway, BatchStudy: batch.batch}
    if type(study) in functions:
        functions[type(study)](study)
        return
    from vcsumo.cli.junction import junction_cmd
    from vcsumo.cli.safety import safety_cmd
    from vcsumo.cli.tradeoff import tradeoff_cmd

    command = junction_cmd if isinstance(study, JunctionStudy) else tradeoff_cmd if isinstance(study, TradeoffStudy) else safety_cmd
    with recording(study.recorded_inputs()):
        click.get_current_context().invoke(command, **study.command_values())  # type: ignore[attr-defined]
