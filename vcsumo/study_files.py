"""Study definitions as files: ``studies/*.yaml`` re-run with ``vcsumo study run FILE``.

A study file names its kind (``study: capacity | headway | batch | junction``), the line and the
options of the matching command, in the same units.  It is validated strictly (unknown keys are
errors) before anything runs, then executed through exactly the same code path as the command
(``vcsumo study capacity ...`` etc.), and the study file is recorded among the results' inputs.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal, Union

from pydantic import Field, TypeAdapter, ValidationError

from vcsumo.config import StrictModel, field_path, read_yaml
from vcsumo.errors import InputError


class _Common(StrictModel):
    line: str = Field(description="Shipped line name or path to a line.yaml (relative to the study file)")
    title: str = ""
    notes: str = ""
    out: str | None = Field(default=None, description="Results folder (default: a new folder under results/)")


class CapacityStudy(_Common):
    study: Literal["capacity"]
    train: str | None = None
    controllers: list[str] = Field(default_factory=lambda: ["cbc", "cbf-cbc"])
    convoy_sizes: list[int] = Field(default_factory=lambda: [1, 2, 3, 4])
    directions: list[Literal["up", "down"]] = Field(default_factory=lambda: ["up", "down"])
    patterns: list[Literal["non-stop", "all-stops"]] | None = None
    block_length_m: float | None = Field(default=None, gt=0)
    step_length_s: float = Field(default=0.5, gt=0, le=2)
    vc_step_length_s: float = Field(default=0.2, gt=0, le=2)
    fixed_time_s: float = Field(default=0.0, ge=0, le=120, description="ETCS fixed times (route setting + MA transmission + reaction), s")
    workers: int | None = Field(default=None, ge=1, description="Parallel processes (default: number of CPUs)")
    seed: int = 42


class HeadwayStudy(_Common):
    study: Literal["headway"]
    regime: Literal["fbs", "mb", "both"] = "both"
    trains: list[str] = Field(default_factory=list)
    points_km: list[float] | None = None
    block_length_m: float | None = Field(default=None, gt=0)
    step_length_s: float = Field(default=0.5, gt=0, le=2)
    trains_per_run: int = Field(default=2, ge=2)


class BatchStudy(_Common):
    study: Literal["batch"]
    timetables: str = Field(description="Glob of timetable files, relative to the repository or the study file")
    regimes: list[Literal["fbs", "mb", "vc"]] = Field(default_factory=lambda: ["fbs", "mb"])
    seeds: int = Field(default=3, ge=1)
    controllers: list[str] = Field(default_factory=list)
    delay_config: str | None = None
    workers: int | None = Field(default=None, ge=0)
    scheduler: str | None = None


class JunctionStudy(_Common):
    study: Literal["junction"]
    train: str | None = None
    controllers: list[str] = Field(default_factory=lambda: ["cbc", "cbf-cbc"])
    junction: str | None = Field(default=None, description="Branch id(s), comma-separated, or 'all' (default: chosen from the line file)")
    first: Literal["main", "branch", "both"] = "both"
    junction_signal: Literal["sumo", "braking-curve", "both"] = "braking-curve"
    directions: list[Literal["up", "down"]] = Field(default_factory=lambda: ["up", "down"])
    offsets_s: list[float] | None = None
    approach_m: float = Field(default=12000.0, gt=0)
    window_m: float = Field(default=5000.0, gt=0)
    block_length_m: float | None = Field(default=None, gt=0)
    step_length_s: float = Field(default=0.5, gt=0, le=2)
    vc_step_length_s: float = Field(default=0.2, gt=0, le=2)
    seed: int = 42


StudyFile = Annotated[Union[CapacityStudy, HeadwayStudy, BatchStudy, JunctionStudy], Field(discriminator="study")]


def load_study(path: str | Path) -> CapacityStudy | HeadwayStudy | BatchStudy | JunctionStudy:
    """Read and validate a study file; errors name the file and the field."""
    path = Path(path)
    data = read_yaml(path)
    if not isinstance(data, dict) or "study" not in data:
        raise InputError(path, "study", "required field is missing (capacity, headway, batch or junction)")
    try:
        return TypeAdapter(StudyFile).validate_python(data)
    except ValidationError as exc:
        err = exc.errors()[0]
        loc = field_path(tuple(x for x in err["loc"] if x not in ("capacity", "headway", "batch", "junction")))
        msg = "unknown key" if err["type"] == "extra_forbidden" else err["msg"].removeprefix("Value error, ")
        raise InputError(path, loc or None, msg) from None


def _resolve(spec: str, base: Path) -> str:
    """A relative path in a study file is relative to the file, unless it names a shipped item."""
    p = Path(spec)
    if p.suffix in (".yaml", ".yml") and not p.is_absolute() and (base / p).exists():
        return str((base / p).resolve())
    return spec


def study_arguments(study, path: Path, out: Path | None) -> list[str]:
    """The command line equivalent to a study file."""
    base = path.parent
    args = ["--line", _resolve(study.line, base)]
    dest = out or (Path(study.out) if study.out else None)
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
        if study.fixed_time_s:
            args += ["--fixed-time-s", str(study.fixed_time_s)]
        if study.workers:
            args += ["--workers", str(study.workers)]
    elif isinstance(study, HeadwayStudy):
        args = ["study", "headway"] + args + ["--regime", study.regime, "--step-length", str(study.step_length_s),
                                              "--trains-per-run", str(study.trains_per_run)]
        for t in study.trains:
            args += ["--train", t]
        if study.points_km:
            args += ["--points", ",".join(map(str, study.points_km))]
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
