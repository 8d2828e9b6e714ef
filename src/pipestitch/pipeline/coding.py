"""The standards stage on a finished run folder OUT: roll reference -> clock positions,
named ovality figures, coded observations and their export files.

Reads only OUT's files (mosaic.png/.json, poses.csv, defects.csv, profile.csv) and,
when given, the dataset (imu.csv, probe.toml, survey.toml), so it runs after
``pipestitch run`` or on its own (``pipestitch export``). Writes, each atomically:

* ``observations.csv``: the coded observations, user-editable; re-coding replaces the
  rows whose ref starts with ``auto:`` and keeps the others byte for byte, as written
  (a row that does not parse is refused with a DatasetError naming the line); an
  ``auto:`` row edited or deleted in review is not generated again
  (standards/observations_review.py);
* ``ovality.csv``: per profile section the named ovality/deflection figures (%);
* ``standards.json``: the reference used, the survey header, the dataset and nominal
  diameter (so a later ``export`` needs neither);
* ``defects.csv`` again, its clock column by the reference (+ ``clock_reference``);
* ``observations.txt`` (EN 13508-2, opened by BCD and closed by BCE),
  ``observations_pacp.csv``, ``observations.json``; ``export --format pacp7`` writes the
  PACP 7 exchange tables, one CSV file per table, into a folder (default ``OUT/pacp7``).
"""

from __future__ import annotations

import csv
import datetime as dt
import json
import math
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from pipestitch.errors import DatasetError
from pipestitch.io.atomic import atomic_write_bytes, atomic_write_text
from pipestitch.io.dataset import read_csv_columns
from pipestitch.io.imu import read_imu
from pipestitch.io.outputs import DEFECT_COLUMNS, read_mosaic, write_csv, write_json
from pipestitch.io.probe_toml import read_probe_toml
from pipestitch.io.survey_toml import SurveyFile, read_survey_toml
from pipestitch.measure.defects import Defect, clock_position
from pipestitch.pipeline.measuring import write_defects_csv
from pipestitch.pipeline.staging import finish_interrupted_commit, out_lock
from pipestitch.report.html import StandardsView
from pipestitch.standards import (
    CONTINUOUS_MIN_M,
    DEFINITIONS,
    Observation,
    RollReference,
    Survey,
    crown_from_imu,
    crown_from_invert,
    detect_invert,
    en_markers,
    pacp_conditions,
    parse_observations_csv,
    relative_reference,
    section_figures,
    user_reference,
    with_nodes,
    write_en13508,
    write_json_text,
    write_observations_csv,
    write_pacp7_tables,
    write_pacp_csv,
)
from pipestitch.standards.invert import invert_columns
from pipestitch.standards.observations import (
    ObservationsFile,
    ProfileSection,
    observations_from_defects,
    observations_from_profile,
    read_observations_file,
    user_rows,
)
from pipestitch.standards.observations_review import DELETED_KEY, deleted_keys, without_superseded

__all__ = ["EXPORTS", "CodedRun", "check_observations", "code_run", "export_run",
           "resolve_reference"]

EXPORTS = {"en13508": "observations.txt", "pacp-csv": "observations_pacp.csv",
           "json": "observations.json", "pacp7": "pacp7"}
# Written by every coding; pacp7 (a folder of tables) only when `export` asks for it, so
# that OUT's outputs stay plain files.
AUTOMATIC = ("en13508", "pacp-csv", "json")
UNITS = ("metric", "imperial")
OVALITY_COLUMNS = ("frame", "z_mm", "mean_id_mm", "min_id_mm", "max_id_mm",
                   *DEFINITIONS)


@dataclass
class CodedRun:
    """What the stage produced (the report shows it)."""

    reference: RollReference
    survey: Survey
    observations: list[Observation]
    defects: list[Defect]
    sections: list[ProfileSection] = field(default_factory=list)
    paths: dict[str, Path] = field(default_factory=dict)

    def report_view(self) -> StandardsView:
        """What the report shows of it."""
        return StandardsView(self.reference.source, self.reference.detail,
                             self.reference.crown_theta_deg, self.observations, self.sections,
                             survey=self.survey)


@dataclass(frozen=True)
class Coding:
    """How observations are coded and exported (survey.toml, else the defaults)."""

    continuous_min_m: float = CONTINUOUS_MIN_M
    spots: str = "deposit"
    units: str = "metric"


def _read_json(path: Path) -> dict:
    try:
        return json.loads(path.read_text(encoding="utf-8")) if path.is_file() else {}
    except (OSError, ValueError) as exc:
        raise DatasetError(path, f"unreadable: {exc}") from None


def resolve_reference(out: Path, *, dataset: Path | None, crown_deg: float | None,
                      image: np.ndarray | None, deg_per_px: float | None) -> RollReference:
    """The roll reference: ``--crown-deg`` when given (an explicit choice wins), else the
    dataset's imu.csv, else a sediment band / water line on the mosaic, else relative."""
    if crown_deg is not None:
        return user_reference(crown_deg)
    imu = read_imu(dataset) if dataset is not None else None
    if imu is not None:
        poses = out / "poses.csv"
        cols = read_csv_columns(poses, ("frame",)) if poses.is_file() else {}
        roll = {int(f): float(r) for f, r in zip(cols.get("frame", []),
                                                 cols.get("roll_deg", []), strict=False)}
        ref = crown_from_imu(roll, imu)
        if ref is not None:
            return ref
    if image is not None and deg_per_px:
        band = detect_invert(image, deg_per_px)
        if band is not None:
            return crown_from_invert(band.theta_deg, (
                f"band {band.width_deg:.0f} deg wide centred at mosaic theta "
                f"{band.theta_deg:.1f} deg, contrast {band.contrast:+.2f}, in "
                f"{100 * band.persistence:.0f} % of the columns"))
    return relative_reference()


def _read_defects(path: Path) -> list[Defect]:
    if not path.is_file():
        return []
    with path.open(newline="", encoding="utf-8") as handle:
        rows = list(csv.DictReader(handle))
    out = []
    for lineno, row in enumerate(rows, start=2):
        try:
            values = {c: row[c] for c in DEFECT_COLUMNS}
            out.append(Defect(**{c: (v if c in ("kind", "clock") else
                                     bool(int(float(v))) if c == "partial" else float(v))
                                 for c, v in values.items()}))
        except (KeyError, TypeError, ValueError) as exc:
            raise DatasetError(path, f"line {lineno}: {exc!r}") from None
    return out


def _sections(out: Path, nominal_mm: float) -> list[ProfileSection]:
    path = out / "profile.csv"
    if not path.is_file():
        return []
    cols = read_csv_columns(path, ("frame",))
    n = len(cols["frame"])
    get = {c: cols.get(c, np.full(n, np.nan)) for c in
           ("z_mm", "diameter_mm", "ovality", "min_radius_mm", "max_radius_mm",
            "major_axis_theta_deg")}
    sections = []
    for i in range(n):
        # min = max radius under the circle model: not measured (ovality NaN).
        measured = bool(np.isfinite(get["ovality"][i]))
        mean_id = float(get["diameter_mm"][i])
        min_id = 2 * float(get["min_radius_mm"][i]) if measured else math.nan
        max_id = 2 * float(get["max_radius_mm"][i]) if measured else math.nan
        figures = section_figures(mean_id, min_id, max_id, nominal_mm, measured=measured)
        sections.append(ProfileSection(int(cols["frame"][i]), float(get["z_mm"][i]), mean_id,
                                       min_id, max_id, figures,
                                       float(get["major_axis_theta_deg"][i])))
    return sections


def _frame_for(out: Path, meta: dict) -> Callable[[float], int | None]:
    """z on the wall -> the frame whose unwrap window is centred nearest to it."""
    poses = out / "poses.csv"
    window = meta.get("window_mm")
    if not poses.is_file() or not window:
        return lambda z: None
    cols = read_csv_columns(poses, ("frame",))
    z = cols.get("z_mm", np.array([]))
    ok = np.isfinite(z)
    frames, centres = cols["frame"][ok].astype(int), z[ok] + (window[0] + window[1]) / 2

    def frame_for(z_mm: float) -> int | None:
        inside = (z[ok] + window[0] <= z_mm) & (z_mm <= z[ok] + window[1])
        if not inside.any():
            return None
        k = np.flatnonzero(inside)[np.argmin(np.abs(centres[inside] - z_mm))]
        return int(frames[k])
    return frame_for


def _nominal(dataset: Path | None, given: float | None, previous: dict) -> float:
    if given is not None:
        return float(given)
    if dataset is not None and (dataset / "probe.toml").is_file():
        return float(read_probe_toml(dataset / "probe.toml").pipe.inner_diameter_mm)
    value = previous.get("nominal_diameter_mm")
    return float(value) if isinstance(value, int | float) else math.nan


def _read_utf8(path: Path) -> str:
    """A text file as it is (no newline translation: kept rows stay byte for byte)."""
    try:
        return path.read_bytes().decode("utf-8")
    except UnicodeDecodeError as exc:
        raise DatasetError(path, f"not UTF-8 text: {exc}") from None


def check_observations(out: str | Path) -> None:
    """Refuse (DatasetError, naming the file and line) an observations.csv whose user rows
    could not be kept: for the commands that write other outputs before re-coding."""
    _earlier_observations(Path(out))


def _earlier_observations(out: Path) -> ObservationsFile | None:
    """An earlier observations.csv, checked: its user rows (not auto:) can be kept as
    written. DatasetError naming the file and the line otherwise."""
    path = out / "observations.csv"
    if not path.is_file():
        return None
    try:
        earlier = read_observations_file(_read_utf8(path))
        user_rows(earlier)
    except ValueError as exc:
        raise DatasetError(path, str(exc)) from None
    return earlier


def code_run(out: str | Path, *, dataset: str | Path | None = None,
             crown_deg: float | None = None, nominal_diameter_mm: float | None = None,
             ovality_threshold_pct: float = 1.0, continuous_min_m: float | None = None,
             units: str | None = None, overview: np.ndarray | None = None) -> CodedRun:
    """Code a finished run: reference, observations, ovality figures and exports.

    Parameters
    ----------
    out : path
        The run folder (``pipestitch run``'s OUT).
    dataset : path, optional
        The dataset, for imu.csv, probe.toml and survey.toml (remembered in
        standards.json).
    crown_deg : float, optional
        Mosaic theta of the crown (``--crown-deg``); overrides every other reference.
    nominal_diameter_mm : float, optional
        Base inside diameter for deflection (default: probe.toml's nominal).
    ovality_threshold_pct : float
        Sections with an ASTM F1216 ovality at least this are coded as deformation.
    continuous_min_m : float, optional
        Features longer than this (m) are start/finish pairs (default: survey.toml's,
        else EN 13508-2's 1 m).
    units : {"metric", "imperial"}, optional
        Units of the PACP 7 tables (default: survey.toml's, else metric).
    overview : numpy.ndarray, optional
        OUT/mosaic.png's pixels, when the caller holds them (the run that wrote them).

    Raises
    ------
    DatasetError
        A file of OUT or the dataset is unreadable or invalid (naming it).
    """
    out = Path(out)
    previous = _read_json(out / "standards.json")
    if dataset is None and previous.get("dataset"):
        dataset = previous["dataset"]
    dataset = Path(dataset) if dataset is not None else None
    folder = dataset if dataset is not None and dataset.is_dir() else None
    meta_file = read_survey_toml(folder) if folder is not None else None
    coding = _coding(meta_file, continuous_min_m, units)
    # only the columns the invert detection reads (a long run's overview is ~10^4 wide)
    image, meta = (read_mosaic(out, columns=invert_columns, image=overview)
                   if (out / "mosaic.json").is_file() else (None, {}))
    reference = resolve_reference(out, dataset=folder, crown_deg=crown_deg, image=image,
                                  deg_per_px=meta.get("deg_per_px"))
    nominal = _nominal(folder, nominal_diameter_mm, previous)
    defects = [_rereferenced(d, reference) for d in _read_defects(out / "defects.csv")]
    sections = _sections(out, nominal)
    start_z = _start_z(meta, sections)
    auto = observations_from_defects(defects, reference, start_z,
                                     frame_for=_frame_for(out, meta),
                                     continuous_min_m=coding.continuous_min_m,
                                     spots=coding.spots)
    auto += observations_from_profile(sections, start_z, threshold_pct=ovality_threshold_pct,
                                      first_continuous=1 + sum(o.continuous.startswith("A")
                                                               for o in auto),
                                      continuous_min_m=coding.continuous_min_m,
                                      reference=reference)
    earlier = _earlier_observations(out)
    kept = [r.observation for r in user_rows(earlier)] if earlier is not None else []
    deleted = deleted_keys(previous)     # auto rows deleted in `review` (edited: by ref)
    auto = without_superseded(auto, kept, deleted)
    observations = sorted(auto + kept, key=lambda o: o.distance_m)
    survey = _survey(out, dataset, meta, sections, start_z, nominal, reference, meta_file)
    coded = CodedRun(reference, survey, observations, defects, sections)
    _write(out, coded, dataset, nominal, start_z, auto, earlier, coding, deleted)
    return coded


def _coding(meta_file: SurveyFile | None, continuous_min_m: float | None,
            units: str | None) -> Coding:
    """The coding settings: arguments first, then survey.toml, then the defaults."""
    if units is not None and units not in UNITS:
        raise ValueError(f"--units: expected one of {', '.join(UNITS)}, got {units!r}")
    if continuous_min_m is not None and not (math.isfinite(continuous_min_m)
                                             and continuous_min_m > 0):
        raise ValueError(f"continuous_min_m: expected a length > 0, got {continuous_min_m}")
    given = meta_file or SurveyFile()
    default = Coding()
    return Coding(continuous_min_m if continuous_min_m is not None
                  else given.continuous_min_m or default.continuous_min_m,
                  given.spots or default.spots, units or given.units or default.units)


def _rereferenced(d: Defect, reference: RollReference) -> Defect:
    return Defect(**{**asdict(d), "clock": clock_position(d.theta_deg, reference.crown_theta_deg)})


def _start_z(meta: dict, sections: list[ProfileSection]) -> float:
    """Distances are from the first wall seen: the mosaic's first column (z0_mm), or
    the first ring when there is no mosaic."""
    if isinstance(meta.get("z0_mm"), int | float):
        return float(meta["z0_mm"])
    zs = [s.z_mm for s in sections if math.isfinite(s.z_mm)]
    return min(zs) if zs else 0.0


def _survey(out: Path, dataset: Path | None, meta: dict, sections: list[ProfileSection],
            start_z: float, nominal: float, reference: RollReference,
            given: SurveyFile | None) -> Survey:
    """The survey header: what survey.toml states, the run's length, nominal size and
    reference; the date and time of coding when survey.toml gives none."""
    end = start_z
    if meta.get("n_cols"):
        end = start_z + meta["n_cols"] * meta["mm_per_px_axial"]
    end = max([end] + [s.z_mm for s in sections if math.isfinite(s.z_mm)])
    now = dt.datetime.now(dt.UTC)
    given = given or SurveyFile()
    name = given.pipe_ref or (dataset.name if dataset is not None else out.name) or "pipe"
    return Survey(name, given.date.isoformat() if given.date else now.strftime("%Y-%m-%d"),
                  given.time or now.strftime("%H:%M"), round((end - start_z) / 1000, 2),
                  round(nominal) if math.isfinite(nominal) else 0, reference.source,
                  start_node=given.start_node or "", finish_node=given.finish_node or "",
                  direction=given.direction or "",
                  # Distances run from the first wall seen, not a node: "other" unless told.
                  reference_point=given.reference_point or "Z",
                  shape=given.shape or "circular", material=given.material or "unknown",
                  operator=given.operator or "", location=given.location or "")


def _write(out: Path, coded: CodedRun, dataset: Path | None, nominal: float,
           start_z: float, auto: list[Observation], earlier: ObservationsFile | None,
           coding: Coding, deleted: list[str]) -> None:
    paths = coded.paths
    text = write_observations_csv(sorted(auto, key=lambda o: o.distance_m), keep=earlier)
    paths["observations"] = atomic_write_text(out / "observations.csv", text)
    if coded.defects:
        paths["defects"] = write_defects_csv(out / "defects.csv", coded.defects,
                                             reference=coded.reference.source)
    rows = [[s.frame, s.z_mm, s.mean_id_mm, s.min_id_mm, s.max_id_mm,
             *asdict(s.figures).values()] for s in coded.sections]
    if rows:
        paths["ovality"] = write_csv(out / "ovality.csv", OVALITY_COLUMNS, rows)
    paths["standards"] = write_json(out / "standards.json", {
        "reference": asdict(coded.reference), "survey": asdict(coded.survey),
        "dataset": str(dataset.resolve()) if dataset is not None else None,
        "nominal_diameter_mm": nominal, "start_z_mm": start_z,
        "start": "first wall seen: the mosaic's first column (z0_mm), else the first ring",
        "coding": asdict(coding), "ovality_definitions": DEFINITIONS, DELETED_KEY: deleted,
    })
    for fmt in AUTOMATIC:
        paths[fmt] = _write_export(out / EXPORTS[fmt], fmt, coded.survey, coded.observations,
                                   coded.sections, coding.units)


def _write_export(path: Path, fmt: str, survey: Survey, observations: list[Observation],
                  sections: list[ProfileSection], units: str) -> Path:
    if fmt == "en13508":
        text = write_en13508([(survey, with_nodes(survey, en_markers(observations)))])
        # The file declares ISO-8859-1 (#A1); characters outside it become "?".
        return atomic_write_bytes(path, text.encode("latin-1", errors="replace"))
    if fmt == "pacp-csv":
        return atomic_write_text(path, write_pacp_csv(observations))
    if fmt == "pacp7":
        conditions = pacp_conditions(en_markers(observations), material=survey.material)
        tables = write_pacp7_tables(survey, conditions, units=units)
        path.mkdir(parents=True, exist_ok=True)
        for name, text in tables.items():
            atomic_write_text(path / f"{name}.csv", text)
        return path
    extra = {"ovality_definitions": DEFINITIONS,
             "sections": [{"frame": s.frame, "z_mm": s.z_mm, **asdict(s.figures)}
                          for s in sections]}
    return atomic_write_text(path, write_json_text(survey, observations, extra))


def export_run(out: str | Path, fmt: str, *, dest: str | Path | None = None,
               crown_deg: float | None = None, dataset: str | Path | None = None,
               units: str | None = None) -> Path:
    """``pipestitch export``: write one format from OUT/observations.csv (re-coding first
    when a reference or dataset is given, or when the run was never coded).

    ``pacp7`` writes a folder (``dest``, default OUT/pacp7) of one CSV file per PACP 7
    table, in ``units`` (default: the run's coding, else metric).
    """
    if fmt not in EXPORTS:
        raise ValueError(f"--format: expected one of {', '.join(EXPORTS)}, got {fmt!r}")
    if units is not None and units not in UNITS:
        raise ValueError(f"--units: expected one of {', '.join(UNITS)}, got {units!r}")
    out = Path(out)
    with out_lock(out, "export"):
        return _export(out, fmt, dest, crown_deg, dataset, units)


def _export(out: Path, fmt: str, dest: str | Path | None, crown_deg: float | None,
            dataset: str | Path | None, units: str | None) -> Path:
    finish_interrupted_commit(out)
    if not (out / "poses.csv").is_file() and not (out / "observations.csv").is_file():
        raise DatasetError(out, "not a run folder (no poses.csv or observations.csv; run "
                                "`pipestitch run` first)")
    if crown_deg is not None or dataset is not None or not (out / "standards.json").is_file():
        code_run(out, dataset=dataset, crown_deg=crown_deg, units=units)
    state = _read_json(out / "standards.json")
    path = out / "observations.csv"
    try:
        observations = parse_observations_csv(_read_utf8(path))
    except FileNotFoundError:
        raise DatasetError(path, "missing") from None
    except ValueError as exc:
        raise DatasetError(path, str(exc)) from None
    try:
        survey = Survey(**state["survey"])
    except (KeyError, TypeError, ValueError) as exc:
        raise DatasetError(out / "standards.json", f"no valid survey: {exc}") from None
    sections = _sections(out, float(state.get("nominal_diameter_mm") or math.nan))
    recorded = (state.get("coding") or {}).get("units")
    chosen = units or (recorded if recorded in UNITS else "metric")
    return _write_export(Path(dest) if dest is not None else out / EXPORTS[fmt], fmt, survey,
                         observations, sections, chosen)
