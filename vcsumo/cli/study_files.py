"""Study definitions as files: ``studies/*.yaml`` re-run with ``vcsumo study run FILE``.

A study file names its kind (``study: capacity | headway | batch | junction | safety``), the line and the
options of the matching command, in the same units.  It is validated strictly (unknown keys are
errors) before anything runs, then executed through exactly the same code path as the command
(``vcsumo study capacity ...`` etc.), and the study file is recorded among the results' inputs.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal, Union

from pydantic import Field, TypeAdapter, ValidationError, field_validator

from vcsumo.config import StrictModel, is_file, read_yaml, validation_error
from vcsumo.errors import InputError
from vcsumo.studies.safety import SafetyCampaign
from vcsumo.studies.tradeoff import TradeoffConfig

BlockLength = Annotated[float, Field(ge=100, le=50000, description="Block length, m (100 m–50 km, as in line files)")]
ConvoySize = Annotated[int, Field(ge=1, le=20, description="Trains in a convoy (1–20: longer convoys are not studied)")]
Step = Annotated[float, Field(gt=0, le=2, description="Simulation step, s (at most 2 s)")]
Workers = Annotated[int, Field(ge=1, le=512, description="Parallel processes (1–512)")]


class _Out(StrictModel):
    title: str = ""
    notes: str = ""
    out: str | None = Field(
        default=None,
        description="Results folder, relative to the current folder, without '..' (default: a new folder under results/); "
        "a study file cannot send results elsewhere, the --out option can",
    )

    @field_validator("out")
    @classmethod
    def _out_stays_here(cls, v: str | None) -> str | None:
        if v is None:
            return v
        p = Path(v)
        if not v.strip() or p.is_absolute() or ".." in p.parts or v.startswith("~") or "\\" in v or "\x00" in v:
            raise ValueError(f"'{v}' must be a relative folder without '..' (a study file may not write outside the current folder; use --out for that)")
        return v


class _Common(_Out):
    line: str = Field(description="Shipped line name or path to a line.yaml (relative to the study file)")


class CapacityStudy(_Common):
    study: Literal["capacity"]
    train: str | None = None
    controllers: list[str] = Field(default_factory=lambda: ["cbc", "cbf-cbc"])
    convoy_sizes: list[ConvoySize] = Field(default_factory=lambda: [1, 2, 3, 4], min_length=1)
    directions: list[Literal["up", "down"]] = Field(default_factory=lambda: ["up", "down"])
    patterns: list[Literal["non-stop", "all-stops"]] | None = None
    block_length_m: BlockLength | None = None
    step_length_s: Step = 0.5
    vc_step_length_s: Step = 0.2
    fixed_time_s: float | None = Field(default=None, ge=0, le=120, description="ETCS fixed times (route setting + MA transmission + reaction), s (default: the assumption set's)")
    assumptions: str | None = Field(default=None, description="Assumption set of the separation model: shipped name or .yaml path (relative to the study file)")
    workers: Workers | None = Field(default=None, description="Parallel processes, 1–512 (default: number of CPUs)")
    seed: int = Field(default=42, ge=0, description="Random seed (not negative)")


class HeadwayStudy(_Common):
    study: Literal["headway"]
    regime: Literal["fbs", "mb", "both"] = "both"
    trains: list[str] = Field(default_factory=list)
    points_km: list[Annotated[float, Field(ge=-100000, le=100000)]] | None = Field(default=None, description="Measuring points, km (the line's chainage)")
    block_length_m: BlockLength | None = None
    step_length_s: Step = 0.5
    trains_per_run: int = Field(default=2, ge=2, le=20, description="Trains released per probe (2–20)")
    assumptions: str | None = Field(default=None, description="Assumption set of the separation model: shipped name or .yaml path (relative to the study file)")


class BatchStudy(_Common):
    study: Literal["batch"]
    timetables: str = Field(description="Glob of timetable files, relative to the repository or the study file")
    regimes: list[Literal["fbs", "mb", "vc"]] = Field(default_factory=lambda: ["fbs", "mb"])
    seeds: int = Field(default=3, ge=1, le=1000, description="Seeds per timetable and regime (1–1,000)")
    controllers: list[str] = Field(default_factory=list)
    delay_config: str | None = None
    workers: Workers | None = Field(default=None, description="Parallel processes, 1–512 (1: in this process; default: number of CPUs)")
    scheduler: str | None = None


class JunctionStudy(_Common):
    study: Literal["junction"]
    train: str | None = None
    controllers: list[str] = Field(default_factory=lambda: ["cbc", "cbf-cbc"])
    junction: str | None = Field(default=None, description="Branch id(s), comma-separated, or 'all' (default: chosen from the line file)")
    first: Literal["main", "branch", "both"] = "both"
    junction_signal: Literal["sumo", "braking-curve", "both"] = "braking-curve"
    directions: list[Literal["up", "down"]] = Field(default_factory=lambda: ["up", "down"])
    offsets_s: list[Annotated[float, Field(ge=-3600, le=3600)]] | None = Field(default=None, description="Release offsets between the services, s (within ±1 h)")
    approach_m: float = Field(default=12000.0, gt=0, le=200000, description="Main-line release distance before the first junction, m (up to 200 km)")
    window_m: float = Field(default=5000.0, gt=0, le=50000, description="Measuring window around the junction, m (up to 50 km)")
    block_length_m: BlockLength | None = None
    step_length_s: Step = 0.5
    vc_step_length_s: Step = 0.2
    seed: int = Field(default=42, ge=0, description="Random seed (not negative)")


class SafetyStudy(_Out, SafetyCampaign):
    """``vcsumo study safety``: the campaign's parameters (:class:`~vcsumo.studies.safety.SafetyCampaign`) and workers."""

    study: Literal["safety"]
    workers: Workers | None = Field(default=None, description="Parallel processes, 1–512 (default: number of CPUs)")


class TradeoffStudy(_Out, TradeoffConfig):
    """``vcsumo study tradeoff``: the study's options (:class:`~vcsumo.studies.tradeoff.TradeoffConfig`)."""

    study: Literal["tradeoff"]


StudyFile = Annotated[Union[CapacityStudy, HeadwayStudy, BatchStudy, JunctionStudy, SafetyStudy, TradeoffStudy], Field(discriminator="study")]


_KINDS = {"capacity": CapacityStudy, "headway": HeadwayStudy, "batch": BatchStudy, "junction": JunctionStudy, "safety": SafetyStudy,
          "tradeoff": TradeoffStudy}


def load_study(path: str | Path) -> CapacityStudy | HeadwayStudy | BatchStudy | JunctionStudy | SafetyStudy:
    """Read and validate a study file; errors name the file and the field.

    Besides the fields' own checks, the names a study refers to are resolved before anything runs:
    the line, the train type(s), the controllers (and their parameter files) and the delay
    configuration must exist.
    """
    path = Path(path)
    data = read_yaml(path)
    if data is None:
        raise InputError(path, None, "the file is empty (expected a mapping with study: capacity, headway, batch, junction or safety)")
    if not isinstance(data, dict):
        raise InputError(path, None, f"expected a mapping with study: capacity, headway, batch, junction or safety, got a {type(data).__name__}")
    if "study" not in data:
        raise InputError(path, "study", "required field is missing (capacity, headway, batch, junction or safety)")
    kind = data.get("study")
    try:
        study = TypeAdapter(StudyFile).validate_python(data)
    except ValidationError as exc:
        model = _KINDS.get(kind) if isinstance(kind, str) else None
        raise validation_error(exc, path, model, skip=tuple(_KINDS)) from None
    check_references(study, path)
    return study


def check_references(study, path: Path) -> None:
    """The line, trains, controllers and delay configuration named by ``study`` exist (InputError if not)."""
    from vcsumo.line import resolve_line_path
    from vcsumo.network_file import network_path

    base = path.parent

    def rewrap(field: str, fn, *args) -> None:
        try:
            fn(*args)
        except InputError as exc:
            if exc.path is None:  # an unknown name: the study file's field is to blame
                raise InputError(path, field, exc.message) from None
            raise

    if isinstance(study, SafetyStudy):
        for i, ln in enumerate(study.lines):
            rewrap(f"lines[{i}]", resolve_line_path, _resolve(ln, base))
        if study.cbf_config:
            rewrap("cbf_config", _check_controller, f"cbf-cbc:{study.cbf_config}")
    elif not (isinstance(study, BatchStudy) and network_path(_resolve(study.line, base)) is not None):  # batch takes a network too
        rewrap("line", resolve_line_path, _resolve(study.line, base))
    trains = [study.train] if getattr(study, "train", None) else list(getattr(study, "trains", []) or [])
    for i, t in enumerate(trains):
        rewrap("train" if hasattr(study, "train") else f"trains[{i}]", _check_train, t)
    for i, c in enumerate(getattr(study, "controllers", []) or []):
        rewrap(f"controllers[{i}]", _check_controller, c)
    if getattr(study, "delay_config", None):
        spec = _resolve(study.delay_config, base)
        if not is_file(spec):
            raise InputError(path, "delay_config", f"delay configuration '{study.delay_config}' not found (relative to the study file or the current folder)")


def _check_train(spec: str) -> None:
    from vcsumo.rolling_stock import load_rolling_stock

    load_rolling_stock(spec)


def _check_controller(spec: str) -> None:
    """A VC controller name (``cbc``, ``cbf-cbc``, ...), optionally with a parameter set after a colon."""
    from vcsumo.control.registry import check_controller

    check_controller(spec, None)


def _resolve(spec: str, base: Path) -> str:
    """A relative path in a study file is relative to the file, unless it names a shipped item."""
    p = Path(spec)
    if p.suffix in (".yaml", ".yml") and not p.is_absolute() and is_file(base / p):
        return str((base / p).resolve())
    return spec


def study_arguments(study, path: Path, out: Path | None) -> list[str]:
    """The command line equivalent to a study file."""
    base = path.parent
    dest = out or (Path(study.out) if study.out else None)
    if isinstance(study, SafetyStudy):
        args = ["study", "safety", "--scenarios", str(study.scenarios), "--lines", ",".join(_resolve(x, base) for x in study.lines),
                "--controllers", ",".join(study.controllers), "--seed", str(study.seed), "--step-s", str(study.step_s),
                "--control-period-s", str(study.control_period_s), "--followers-max", str(study.followers_max), "--kinds", ",".join(study.kinds),
                "--channel-period-s", str(study.channel_period_s), "--loss-max", str(study.loss_max), "--delay-max-s", str(study.delay_max_s),
                "--mean-extra-max-s", str(study.mean_extra_max_s), "--outage-probability", str(study.outage_probability),
                "--outage-max-s", str(study.outage_max_s), "--corner-probability", str(study.corner_probability),
                "--position-error-max-m", str(study.position_error_max_m), "--max-duration-s", str(study.max_duration_s)]
        if study.cbf_config:
            args += ["--cbf", _resolve(study.cbf_config, base)]
        if study.workers:
            args += ["--workers", str(study.workers)]
        return args + (["--out", str(dest)] if dest is not None else [])
    if isinstance(study, TradeoffStudy):
        from vcsumo.cli.tradeoff import tradeoff_arguments

        assumptions = _resolve(study.assumptions, base) if study.assumptions else None
        return tradeoff_arguments(study, _resolve(study.line, base), assumptions) + (["--out", str(dest)] if dest is not None else [])
    args = ["--line", _resolve(study.line, base)]
    if isinstance(study, CapacityStudy):
        args = ["study", "capacity"] + args
        if study.train:
            args += ["--train", study.train]
        args += ["--controllers", ",".join(study.controllers), "--convoy-sizes", ",".join(map(str, study.convoy_sizes)),
                 "--directions", ",".join(study.directions), "--step-length", str(study.step_length_s),
                 "--vc-step-length", str(study.vc_step_length_s), "--seed", str(study.seed)]
        if study.patterns:
            args += ["--patterns", ",".join(study.patterns)]
        if study.block_length_m:
            args += ["--block-length-m", str(study.block_length_m)]
        if study.fixed_time_s is not None:
            args += ["--fixed-time-s", str(study.fixed_time_s)]
        if study.assumptions:
            args += ["--assumptions", _resolve(study.assumptions, base)]
        if study.workers:
            args += ["--workers", str(study.workers)]
    elif isinstance(study, HeadwayStudy):
        args = ["study", "headway"] + args + ["--regime", study.regime, "--step-length", str(study.step_length_s),
                                              "--trains-per-run", str(study.trains_per_run)]
        for t in study.trains:
            args += ["--train", t]
        if study.points_km:
            args += ["--points", ",".join(map(str, study.points_km))]
        if study.assumptions:
            args += ["--assumptions", _resolve(study.assumptions, base)]
        if study.block_length_m:
            args += ["--block-length-m", str(study.block_length_m)]
    elif isinstance(study, BatchStudy):
        args = ["batch"] + args + ["--timetables", study.timetables, "--regimes", ",".join(study.regimes), "--seeds", str(study.seeds)]
        if study.controllers:
            args += ["--controllers", ",".join(study.controllers)]
        if study.delay_config:
            args += ["--delay-config", _resolve(study.delay_config, base)]
        if study.workers is not None:
            args += ["--workers", str(study.workers)]
        if study.scheduler:
            args += ["--scheduler", study.scheduler]
    else:
        args = ["study", "junction"] + args + ["--controllers", ",".join(study.controllers), "--first", study.first,
                                               "--junction-signal", study.junction_signal, "--directions", ",".join(study.directions),
                                               "--approach-m", str(study.approach_m), "--window-m", str(study.window_m),
                                               "--step-length", str(study.step_length_s), "--vc-step-length", str(study.vc_step_length_s),
                                               "--seed", str(study.seed)]
        if study.train:
            args += ["--train", study.train]
        if study.junction:
            args += ["--junction", study.junction]
        if study.offsets_s:
            args += ["--offsets", ",".join(f"{o:g}" for o in study.offsets_s)]
        if study.block_length_m:
            args += ["--block-length-m", str(study.block_length_m)]
    if dest is not None:
        args += ["--out", str(dest)]
    return args
