"""The review page of a finished run: its data from OUT's files, and observation edits.

:func:`review_data` gathers what the page shows (report/review_page.py) from OUT:
mosaic.json, tiles/, mosaic.png (its no-data mask), defects.csv, observations.csv,
standards.json (clock reference, start of the distances), poses.csv and profile.csv.
:func:`write_review_page` writes ``OUT/review.html``, the read-only page that works
from file://. :func:`edit_observations` applies one edit from the page (add, change or
delete a row) to ``OUT/observations.csv``, validated here, never in the browser:
codes, characterisations, whole numbers, clock hours 1..12, sizes of the text. Rows
not edited stay as they were written, byte for byte; the file is replaced atomically,
the automatic exports (observations.txt, _pacp.csv, .json) are written again from it
and so is the coded observations section of report.html. An edited or deleted
``auto:`` row stays superseded on every later re-coding
(:mod:`pipestitch.standards.observations_review`).
"""

from __future__ import annotations

import base64
import csv
import hashlib
import json
import math
import os
import re
from dataclasses import dataclass, replace
from pathlib import Path

import cv2
import numpy as np

from pipestitch.errors import DatasetError
from pipestitch.io.atomic import atomic_write_text
from pipestitch.io.outputs import write_json
from pipestitch.io.tiles import DZI_NAME, read_dzi
from pipestitch.pipeline.coding import AUTOMATIC, export_run
from pipestitch.pipeline.staging import OutputBusy, out_lock
from pipestitch.pipeline.stitched_output import TILES
from pipestitch.report.html import StandardsView, with_observation_section
from pipestitch.report.review_page import REVIEW_NAME, ReviewData, ReviewGrid, render_review
from pipestitch.standards.observations import (
    AUTO_PREFIX,
    OBSERVATION_COLUMNS,
    Observation,
    ObservationsFile,
    csv_record,
    is_auto,
    observation_from_fields,
    read_observations_file,
    user_rows,
    write_observations_csv,
)
from pipestitch.standards.observations_review import (
    DELETED_KEY,
    REVIEWED_PREFIX,
    auto_key,
    deleted_keys,
    replaced_key,
    reviewed_ref,
)

__all__ = ["CODES", "REVIEWED_PREFIX", "Edit", "EditError", "edit_observations",
           "observation_rows", "read_observations", "read_run_csv", "refresh_report",
           "render_review_page", "review_data", "validated_observation", "write_review_page"]

OBSERVATIONS = "observations.csv"
STANDARDS = "standards.json"
REPORT = "report.html"
NODATA_MAX_PX = 4096          # the no-data mask is shown at most this wide (a long run's)
# EN 13508-2 main codes of a pipe (B + group A-D + a letter) the form offers by name;
# any code of that pattern is accepted.
CODES = {"BAA": "deformation", "BAB": "cracks", "BAC": "break/collapse",
         "BAF": "surface damage", "BAI": "intruding sealing material", "BAJ": "displaced joint",
         "BBA": "roots", "BBB": "attached deposits", "BBC": "settled deposits",
         "BBF": "infiltration", "BDB": "general remark"}
_CODE = re.compile(r"B[A-D][A-Z]", re.ASCII)
_CHAR = re.compile(r"[A-Z]?", re.ASCII)
_CONTINUOUS = re.compile(r"[ABSF]\d{1,3}", re.ASCII)   # start/finish markers: A1, B1
TEXT_LIMITS = {"remark": 500, "ref": 200, "continuous": 8}
QUANT_MAX = 100_000           # mm or %: larger is a typing error
DISTANCE_MAX_M = 100_000.0


class EditError(ValueError):
    """An edit the server refuses; ``status`` is its HTTP status (400 bad input, 404 no
    such row, 409 the file changed since the page read it)."""

    def __init__(self, message: str, status: int = 400) -> None:
        super().__init__(message)
        self.status = status


# --- reading OUT ---------------------------------------------------------------------------

def _number(text: str | None) -> float | None:
    try:
        value = float(text) if text not in (None, "") else math.nan
    except ValueError:
        return None
    return value if math.isfinite(value) else None


def read_run_csv(path: Path) -> list[dict[str, str]]:
    """The rows of a CSV of OUT as dicts ([] when it is missing); DatasetError naming it."""
    if not path.is_file():
        return []
    try:
        with path.open(newline="", encoding="utf-8-sig") as handle:
            return list(csv.DictReader(handle))
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise DatasetError(path, f"unreadable: {exc}") from None


def _columns(path: Path, names: tuple[str, ...]) -> dict[str, list[float | None]]:
    """Numeric columns of a CSV (None for empty, NaN or text)."""
    rows = read_run_csv(path)
    return {n: [_number(r.get(n)) for r in rows] for n in names}


def _defects(path: Path) -> list[dict[str, object]]:
    out = []
    for line, row in enumerate(read_run_csv(path), start=2):
        values = {k: _number(v) for k, v in row.items() if k not in ("kind", "clock")}
        if values.get("z_mm") is None or values.get("theta_deg") is None:
            raise DatasetError(path, f"line {line}: no z_mm or theta_deg")
        out.append({**{k: (0.0 if v is None else v) for k, v in values.items()},
                    "kind": row.get("kind", ""), "clock": row.get("clock", "")})
    return out


def _read_json(path: Path) -> dict:
    try:
        return json.loads(path.read_text(encoding="utf-8")) if path.is_file() else {}
    except (OSError, ValueError) as exc:
        raise DatasetError(path, f"unreadable: {exc}") from None


def read_observations(out: Path) -> tuple[ObservationsFile | None, str]:
    """observations.csv as read and the digest of its bytes ("" when there is none)."""
    path = out / OBSERVATIONS
    if not path.is_file():
        return None, ""
    data = path.read_bytes()
    try:
        return read_observations_file(data.decode("utf-8")), hashlib.sha256(data).hexdigest()
    except (UnicodeDecodeError, ValueError) as exc:
        raise DatasetError(path, str(exc)) from None


def observation_rows(file: ObservationsFile | None) -> list[dict[str, object]]:
    """The rows as the page lists them: the observation's fields and ``index``, the row's
    position in the file."""
    if file is None:
        return []
    return [{"index": k, **{c: getattr(r.observation, c) for c in OBSERVATION_COLUMNS}}
            for k, r in enumerate(file.rows)]


def _nodata_png(out: Path, overview: np.ndarray | None = None) -> str | None:
    """The overview's no-data pixels as a translucent red PNG data URI (``overview``:
    OUT/mosaic.png's pixels, when the caller holds them)."""
    image = (overview if overview is not None
             else cv2.imread(str(out / "mosaic.png"), cv2.IMREAD_UNCHANGED))
    if image is None:
        return None
    empty = image[..., -1] == 0 if image.ndim == 3 and image.shape[2] == 4 else (
        image == 0 if image.ndim == 2 else image.max(axis=2) == 0)
    scale = min(1.0, NODATA_MAX_PX / max(empty.shape))
    if scale < 1.0:
        empty = cv2.resize(empty.astype(np.uint8), None, fx=scale, fy=scale,
                           interpolation=cv2.INTER_NEAREST).astype(bool)
    rgba = np.zeros((*empty.shape, 4), np.uint8)
    rgba[empty] = (40, 40, 255, 255)          # BGRA: red
    ok, png = cv2.imencode(".png", rgba)
    if not ok:
        return None
    return "data:image/png;base64," + base64.b64encode(png.tobytes()).decode("ascii")


def _grid(meta: dict, path: Path) -> ReviewGrid:
    full = meta.get("full_resolution") or meta
    try:
        return ReviewGrid(float(full["z0_mm"]), float(full["mm_per_px_axial"]),
                          float(full["deg_per_px"]), int(full["n_rows"]), int(full["n_cols"]),
                          float(full["mm_per_px_circumferential"]))
    except (KeyError, TypeError, ValueError) as exc:
        raise DatasetError(path, f"no full-resolution scale ({exc!r})") from None


def _tiles(out: Path, page_dir: Path) -> dict[str, object]:
    tiles = out / TILES
    try:
        source = read_dzi(tiles / DZI_NAME)
    except ValueError as exc:
        raise DatasetError(tiles / DZI_NAME, f"no mosaic tiles ({exc}); run `pipestitch run` "
                                             "again") from None
    relative = Path(os.path.relpath(tiles.resolve(), page_dir.resolve()))
    source["Image"]["Url"] = (relative / "mosaic_files").as_posix() + "/"
    return source


def review_data(out: str | Path, *, editable: bool = False,
                frames_url: str | None = None,
                overview: np.ndarray | None = None) -> ReviewData:
    """What the review page of the run in ``out`` shows.

    Parameters
    ----------
    out : path
        The run folder (``pipestitch run``'s OUT), with a mosaic.
    editable : bool
        The page is served and may edit observations.
    frames_url : str, optional
        The server's URL of source frames (None: the page shows the poses only).
    overview : numpy.ndarray, optional
        OUT/mosaic.png's pixels, when the caller holds them (not read again).

    Raises
    ------
    DatasetError
        Naming the file that is missing or unreadable (no mosaic: no review).
    """
    out = Path(out)
    meta = _read_json(out / "mosaic.json")
    if not meta:
        raise DatasetError(out / "mosaic.json", "missing: the run has no mosaic to review")
    standards = _read_json(out / "standards.json")
    reference = standards.get("reference") or {}
    grid = _grid(meta, out / "mosaic.json")
    file, version = read_observations(out)
    window = meta.get("window_mm") or [0.0, 0.0]
    return ReviewData(
        title=f"pipestitch review: {Path(str(standards.get('dataset') or out)).name}",
        tiles=_tiles(out, out), grid=grid,
        crown_theta_deg=float(reference.get("crown_theta_deg", 270.0)),
        reference=str(reference.get("source", "relative")),
        start_z_mm=float(standards.get("start_z_mm", grid.z0_mm)),
        window_mm=(float(window[0]), float(window[1])),
        nominal_diameter_mm=float(standards.get("nominal_diameter_mm") or math.nan),
        defects=_defects(out / "defects.csv"), observations=observation_rows(file),
        version=version,
        poses=_columns(out / "poses.csv", ("frame", "z_mm", "roll_deg", "alpha_deg",
                                           "beta_deg", "dx_mm", "dy_mm")),
        profile=_columns(out / "profile.csv", ("z_mm", "diameter_mm", "ovality")),
        nodata=_nodata_png(out, overview), editable=editable, frames_url=frames_url, codes=CODES)


def _json_ready(data: ReviewData) -> ReviewData:
    if not math.isfinite(data.nominal_diameter_mm):
        data.nominal_diameter_mm = 0.0
    return data


def render_review_page(out: str | Path, **options: object) -> str:
    """The review page's text for the run in ``out`` (options as :func:`review_data`)."""
    return render_review(_json_ready(review_data(out, **options)))  # type: ignore[arg-type]


def write_review_page(out: str | Path, overview: np.ndarray | None = None) -> Path:
    """Write the read-only ``OUT/review.html`` (works from file://); its path
    (``overview``: OUT/mosaic.png's pixels, when the caller holds them)."""
    out = Path(out)
    return atomic_write_text(out / REVIEW_NAME, render_review_page(out, overview=overview))


# --- editing observations.csv ---------------------------------------------------------------

def _text(fields: dict[str, object], name: str) -> str:
    value = fields.get(name, "")
    if value is None:
        return ""
    if isinstance(value, bool) or not isinstance(value, str | int | float):
        raise EditError(f"{name}: expected text or a number, got {type(value).__name__}")
    text = str(value)
    limit = TEXT_LIMITS.get(name, 40)
    if len(text) > limit:
        raise EditError(f"{name}: at most {limit} characters, got {len(text)}")
    if any(ord(c) < 32 for c in text):
        raise EditError(f"{name}: control characters (line breaks, tabs) are not allowed")
    return text.strip() if name != "remark" else text


def _check_codes(o: Observation) -> None:
    if not _CODE.fullmatch(o.code):
        raise EditError(f"code: expected an EN 13508-2 main code of a pipe such as BAC "
                        f"(B, A-D, a letter), got {o.code!r}")
    for name in ("char1", "char2"):
        if not _CHAR.fullmatch(getattr(o, name)):
            raise EditError(f"{name}: expected one capital letter or nothing, "
                            f"got {getattr(o, name)!r}")
    if o.continuous and not _CONTINUOUS.fullmatch(o.continuous):
        raise EditError(f"continuous: expected a marker such as A1 or B1, got {o.continuous!r}")


def _check_numbers(o: Observation) -> None:
    if o.distance_m > DISTANCE_MAX_M:
        raise EditError(f"distance_m: expected at most {DISTANCE_MAX_M:g} m, got {o.distance_m}")
    for name in ("quant1", "quant2"):
        value = getattr(o, name)
        if value is not None and not 0 <= value <= QUANT_MAX:
            raise EditError(f"{name}: expected a whole number 0..{QUANT_MAX}, got {value}")
    if o.clock_to is not None and o.clock_from is None:
        raise EditError("clock_to: given without clock_from")


def validated_observation(fields: object) -> Observation:
    """The observation the page's ``fields`` describe, checked.

    Raises
    ------
    EditError
        Naming the field: unknown fields, a code not of the EN 13508-2 pipe pattern,
        characterisations other than one capital letter, numbers that are not numbers
        or not whole, clock hours outside 1..12, text too long or with control characters.
    """
    if not isinstance(fields, dict):
        raise EditError("fields: expected an object of observation fields")
    unknown = sorted(set(fields) - set(OBSERVATION_COLUMNS))
    if unknown:
        raise EditError(f"unknown field(s) {', '.join(map(str, unknown))}; expected "
                        f"{', '.join(OBSERVATION_COLUMNS)}")
    texts = {name: _text(fields, name) for name in OBSERVATION_COLUMNS}
    texts["code"], texts["char1"], texts["char2"] = (texts[k].upper()
                                                     for k in ("code", "char1", "char2"))
    try:
        observation = observation_from_fields(texts)
    except ValueError as exc:
        raise EditError(str(exc)) from None
    _check_codes(observation)
    _check_numbers(observation)
    return observation


def _record(o: Observation, newline: str) -> str:
    """One observations.csv record for ``o`` (text cells neutralised as the file's)."""
    text = write_observations_csv([o])[len(csv_record(OBSERVATION_COLUMNS)):]
    return text[:-1] + newline


def _newline(file: ObservationsFile | None) -> str:
    header = file.header if file is not None else ""
    return header[len(header.rstrip("\r\n")):] or "\n"


@dataclass(frozen=True)
class Edit:
    """One change to observations.csv: ``action`` add, change or delete; ``index`` the
    row (change, delete); ``fields`` the observation (add, change); ``version`` the
    digest of the file the page read (empty when it read none)."""

    action: str
    index: int | None = None
    fields: object = None
    version: str = ""


def _reviewed(o: Observation, before: Observation) -> Observation:
    """``o``, the edit of the row ``before``: the edit of an ``auto:`` row is stored as
    ``reviewed:`` (it then supersedes that row on re-coding), and a ``reviewed:`` row
    keeps its ref, whatever ref the page sent."""
    if is_auto(before):
        return replace(o, ref=reviewed_ref(before))
    if before.ref.startswith(REVIEWED_PREFIX):
        return replace(o, ref=before.ref)
    return o


def _added(o: Observation) -> Observation:
    if is_auto(o):
        raise EditError(f"ref: {AUTO_PREFIX} rows are generated by re-coding (it would "
                        "replace this one); give another reference")
    return o


def _edited_rows(file: ObservationsFile | None, edit: Edit) -> list[tuple[float, str]]:
    """(distance, record text) of every row after ``edit``, in the file's order."""
    rows = [(r.observation.distance_m, r.text) for r in file.rows] if file is not None else []
    newline = _newline(file)
    if rows and not rows[-1][1].endswith(("\n", "\r")):
        rows[-1] = (rows[-1][0], rows[-1][1] + newline)
    if edit.action == "add":
        o = _added(validated_observation(edit.fields))
        rows.append((o.distance_m, _record(o, newline)))
        return sorted(rows, key=lambda row: row[0])     # stable: the others keep their order
    if edit.index is None or not 0 <= edit.index < len(rows):
        raise EditError(f"no observation row {edit.index} (the file has {len(rows)})", 404)
    if edit.action == "delete":
        return rows[:edit.index] + rows[edit.index + 1:]
    if edit.action != "change":
        raise EditError(f"action: expected add, change or delete, got {edit.action!r}")
    o = _reviewed(validated_observation(edit.fields), file.rows[edit.index].observation)
    rows[edit.index] = (o.distance_m, _record(o, newline))
    return sorted(rows, key=lambda row: row[0])


def edit_observations(out: str | Path, edit: Edit) -> tuple[list[dict[str, object]], str]:
    """Apply ``edit`` to ``OUT/observations.csv``; the rows and the new version.

    The file is replaced atomically; then the automatic exports, the coded
    observations of report.html and review.html are written again from it. An edited
    ``auto:`` row is stored as ``reviewed:`` and a deleted one is listed in
    standards.json: re-coding the run replaces the ``auto:`` rows, less those, and
    keeps the others.

    Raises
    ------
    EditError
        Bad input (400), no such row (404), the file changed since the page read it
        or another command is writing into OUT (409).
    DatasetError
        observations.csv is unreadable.
    """
    out = Path(out)
    try:
        with out_lock(out, "review"):
            return _edit(out, edit)
    except OutputBusy as exc:
        raise EditError(f"{exc.problem}; try again when it has finished", 409) from None


def _edit(out: Path, edit: Edit) -> tuple[list[dict[str, object]], str]:
    file, version = read_observations(out)
    if edit.version != version:
        raise EditError(f"{OBSERVATIONS} changed since the page read it; reload the page", 409)
    header = file.header if file is not None else csv_record(OBSERVATION_COLUMNS)
    text = header + "".join(t for _, t in _edited_rows(file, edit))
    try:
        edited = read_observations_file(text)
        user_rows(edited)                          # the result must read back and keep
    except ValueError as exc:
        raise EditError(f"{OBSERVATIONS}: {exc}") from None
    atomic_write_text(out / OBSERVATIONS, text)
    if edit.action == "delete" and file is not None:   # after: a failed save deletes nothing
        _remember_deleted(out, file.rows[edit.index].observation)
    if (out / STANDARDS).is_file():
        for fmt in AUTOMATIC:
            export_run(out, fmt)
    refresh_report(out, [r.observation for r in edited.rows])
    write_review_page(out)
    file, version = read_observations(out)
    return observation_rows(file), version


def _remember_deleted(out: Path, o: Observation) -> None:
    """A deleted ``auto:`` row (or the ``reviewed:`` row that replaced one) listed in
    standards.json, so that re-coding does not generate it again."""
    key = auto_key(o) if is_auto(o) else replaced_key(o)
    state = _read_json(out / STANDARDS)
    if key is None or not state:      # never coded: nothing generates the row again
        return
    write_json(out / STANDARDS, {**state, DELETED_KEY: sorted({*deleted_keys(state), key})})


def refresh_report(out: str | Path, observations: list[Observation]) -> Path | None:
    """Render the coded observations section of ``OUT/report.html`` again from
    ``observations`` (as observations.csv now holds them), atomically; the report's
    path, or None when there is no report or it has no such section."""
    path = Path(out) / REPORT
    if not path.is_file():
        return None
    state = _read_json(Path(out) / STANDARDS)
    reference = state.get("reference") or {}
    view = StandardsView(str(reference.get("source", "relative")),
                         str(reference.get("detail", "")),
                         float(reference.get("crown_theta_deg", 270.0)),
                         sorted(observations, key=lambda o: o.distance_m))
    text = with_observation_section(path.read_text(encoding="utf-8"), view)
    return atomic_write_text(path, text) if text is not None else None
