"""The review server: what it refuses (bad input, paths outside OUT, other hosts), how an
edit lands in observations.csv (other rows byte for byte, atomically, re-exported, the
report's observations rendered again), that an edited or deleted generated row stays
superseded when the run is coded again, and the fitted ellipse of the frame marker."""

from __future__ import annotations

import http.client
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from pipestitch.cli.app import app
from pipestitch.geometry.cylinder import PipeSection
from pipestitch.pipeline.coding import code_run
from pipestitch.pipeline.review import (
    Edit,
    EditError,
    edit_observations,
    read_observations,
    validated_observation,
)
from pipestitch.pipeline.review_server import ReviewServer
from pipestitch.pipeline.source_frames import FramePoses, SourceFrames
from pipestitch.report.html import OBSERVATIONS_BEGIN, OBSERVATIONS_END
from pipestitch.standards.observations import Observation, parse_observations_csv
from pipestitch.standards.observations_review import without_superseded

GOOD = {"distance_m": "0.05", "code": "BAB", "char1": "A", "quant1": "2", "clock_from": "3",
        "remark": "crack seen in review", "ref": "review: test"}


@pytest.fixture(scope="module")
def run_out(tmp_path_factory: pytest.TempPathFactory, simulate_small) -> Path:
    root = tmp_path_factory.mktemp("review")
    ds = simulate_small(root / "ds", "--scenario", "test_piece", "--pairs", "6")
    out = root / "out"
    result = CliRunner().invoke(app, ["run", str(ds), "--out", str(out), "--quiet"])
    assert result.exit_code == 0, result.output
    return out


@pytest.fixture
def out(run_out: Path, tmp_path: Path) -> Path:
    copy = tmp_path / "out"
    shutil.copytree(run_out, copy)
    return copy


def _request(server: ReviewServer, method: str, path: str, body: object = None, *,
             headers: dict[str, str] | None = None) -> tuple[int, dict]:
    port = server.httpd.server_address[1]
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=20)
    data = None if body is None else json.dumps(body).encode()
    sent = {"Content-Type": "application/json", **(headers or {})}
    conn.request(method, path, body=data, headers=sent)
    response = conn.getresponse()
    raw = response.read()
    conn.close()
    return response.status, (json.loads(raw) if raw.startswith(b"{") else {})


def _version(server: ReviewServer) -> str:
    return _request(server, "GET", "/api/observations")[1]["version"]


@pytest.mark.parametrize("field,value,message", [
    ("code", "XYZ", "main code"), ("code", "B=1", "main code"), ("char1", "ab", "capital"),
    ("clock_from", "13", "1..12"), ("clock_from", "0", "1..12"), ("quant1", "abc", "number"),
    ("quant1", "2.5", "whole"), ("quant1", "-4", "0.."), ("distance_m", "nan", "finite"),
    ("distance_m", "-1", "finite"), ("remark", "a\nb", "control"), ("remark", "x" * 600, "500"),
    ("continuous", "Q1", "marker"), ("color", "red", "unknown field")])
def test_bad_fields_are_refused_with_the_field_named(field: str, value: str,
                                                     message: str) -> None:
    with pytest.raises(EditError, match=message) as info:
        validated_observation({**GOOD, field: value})
    assert info.value.status == 400


def test_an_added_row_cannot_claim_to_be_generated(out: Path) -> None:
    with pytest.raises(EditError, match="re-coding"):
        edit_observations(out, Edit("add", None, {**GOOD, "ref": "auto:D9 mine"},
                                    read_observations(out)[1]))


def test_clock_to_needs_clock_from() -> None:
    with pytest.raises(EditError, match="clock_to"):
        validated_observation({**GOOD, "clock_from": "", "clock_to": "4"})


def test_server_refuses_bad_input_paths_outside_and_other_hosts(out: Path) -> None:
    before = (out / "observations.csv").read_bytes()
    (out.parent / "secret.txt").write_text("outside")
    with ReviewServer(out) as server:
        version = _version(server)
        assert _request(server, "POST", "/api/observations",
                        {"version": version, "fields": {**GOOD, "clock_from": "13"}})[0] == 400
        status, answer = _request(server, "POST", "/api/observations",
                                  {"version": version, "fields": {**GOOD, "code": "ZZZ"}})
        assert status == 400 and "code" in answer["error"]
        assert _request(server, "POST", "/api/observations",
                        {"version": "stale", "fields": GOOD})[0] == 409
        assert _request(server, "PUT", "/api/observations/999",
                        {"version": version, "fields": GOOD})[0] == 404
        assert _request(server, "POST", "/api/observations", {"version": version, "fields": GOOD},
                        headers={"Content-Type": "text/plain"})[0] == 403
        assert _request(server, "POST", "/api/observations", {"version": version, "fields": GOOD},
                        headers={"Origin": "http://evil.example"})[0] == 403
        assert _request(server, "GET", "/", headers={"Host": "evil.example"})[0] == 403
        for path in ("/../secret.txt", "/%2e%2e/secret.txt", "/tiles/../../secret.txt"):
            assert _request(server, "GET", path)[0] == 403, path
        assert _request(server, "GET", "/mosaic.json")[0] == 200
        assert _request(server, "GET", "/api/frame?frame=1&z=nan&theta=3")[0] == 400
    assert (out / "observations.csv").read_bytes() == before
    assert not any(p.name.endswith(".tmp") for p in out.iterdir())


def test_an_edit_keeps_the_other_rows_byte_for_byte_and_re_exports(out: Path) -> None:
    path = out / "observations.csv"
    text = path.read_bytes().decode()
    user_row = '0.01,BDB,,,,,"=SUM(A1)",,,,"my own, kept"\r\n'
    path.write_bytes((text + user_row).encode())
    with ReviewServer(out) as server:
        status, answer = _request(server, "POST", "/api/observations",
                                  {"version": _version(server), "fields": GOOD})
        assert status == 200, answer
        auto = next(o for o in answer["observations"] if o["ref"].startswith("auto:"))
        changed = {**{k: auto[k] for k in GOOD}, "code": "BAC", "char1": "B", "quant1": "7",
                   "ref": auto["ref"]}
        status, answer = _request(server, "PUT", f"/api/observations/{auto['index']}",
                                  {"version": answer["version"], "fields": changed})
        assert status == 200, answer
    after = path.read_bytes().decode()
    assert user_row in after
    for line in text.splitlines(keepends=True)[1:]:
        if line.split(",")[-1] != auto["ref"] + "\n":
            assert line in after
    observations = parse_observations_csv(after)
    assert any(o.code == "BAB" and o.remark == "crack seen in review" for o in observations)
    assert any(o.ref == "reviewed:" + auto["ref"][len("auto:"):] and o.quant1 == 7
               for o in observations)
    assert "crack seen in review" in (out / "observations.txt").read_bytes().decode("latin-1")
    assert "crack seen in review" in (out / "observations_pacp.csv").read_text()


def test_delete_removes_one_row(out: Path) -> None:
    before = parse_observations_csv((out / "observations.csv").read_text())
    version = read_observations(out)[1]
    rows, _ = edit_observations(out, Edit("delete", 0, None, version))
    assert len(rows) == len(before) - 1


def test_review_command_bad_input_exits_2(tmp_path: Path) -> None:
    runner = CliRunner()
    result = runner.invoke(app, ["review", str(tmp_path / "missing"), "--no-browser"])
    assert result.exit_code == 2 and "not a folder" in result.output
    result = runner.invoke(app, ["review", str(tmp_path), "--no-browser"])
    assert result.exit_code == 2 and "mosaic.json" in result.output
    assert "Traceback" not in result.output


def _auto_rows(out: Path) -> list[Observation]:
    return [o for o in parse_observations_csv((out / "observations.csv").read_text())
            if o.ref.startswith("auto:")]


def test_an_edited_auto_row_replaces_it_on_every_re_coding(out: Path) -> None:
    path = out / "observations.csv"
    user_row = '0.02,BDB,,,,,"my own, kept",,,,mine\r\n'
    path.write_bytes(path.read_bytes() + user_row.encode())
    first, gone = _auto_rows(out)[:2]
    with ReviewServer(out) as server:
        rows = _request(server, "GET", "/api/observations")[1]
        edited = next(o for o in rows["observations"] if o["ref"] == first.ref)
        fields = {**{k: edited[k] for k in GOOD}, "quant1": "9", "ref": "typed over",
                  "remark": "hole checked in review"}
        status, answer = _request(server, "PUT", f"/api/observations/{edited['index']}",
                                  {"version": rows["version"], "fields": fields})
        assert status == 200, answer
        deleted = next(o for o in answer["observations"] if o["ref"] == gone.ref)
        status, answer = _request(server, "DELETE", f"/api/observations/{deleted['index']}",
                                  {"version": answer["version"]})
        assert status == 200, answer
    reviewed = "reviewed:" + first.ref[len("auto:"):]
    assert json.loads((out / "standards.json").read_text())["deleted_auto"] == [gone.ref]
    for _ in range(2):           # coded again twice: still once, the original never back
        code_run(out)
        text = path.read_bytes().decode()
        observations = parse_observations_csv(text)
        assert [o.ref for o in observations].count(reviewed) == 1
        assert not {first.ref, gone.ref} & {o.ref for o in observations}
        assert user_row in text                              # byte for byte
        assert len(observations) == len(rows["observations"]) - 1     # the one deleted
    result = CliRunner().invoke(app, ["export", str(out), "--format", "pacp-csv"])
    assert result.exit_code == 0, result.output
    pacp = (out / "observations_pacp.csv").read_text()
    assert pacp.count("hole checked in review") == 1
    assert first.ref not in pacp and gone.ref not in pacp


def test_deleting_a_reviewed_row_keeps_its_auto_row_away(out: Path) -> None:
    target = _auto_rows(out)[0]
    file, version = read_observations(out)
    index = next(k for k, r in enumerate(file.rows) if r.observation.ref == target.ref)
    fields = {c: getattr(target, c) for c in ("distance_m", "code", "char1", "ref")}
    rows, version = edit_observations(out, Edit("change", index, fields, version))
    index = next(r["index"] for r in rows if str(r["ref"]).startswith("reviewed:"))
    edit_observations(out, Edit("delete", index, None, version))
    code_run(out)
    assert target.ref not in (out / "observations.csv").read_text()


def test_a_pair_s_rows_are_superseded_one_by_one() -> None:
    start = Observation(1.0, "BAA", continuous="A1", ref="auto:P profile frames 1-90")
    finish = Observation(2.5, "BAA", continuous="B1", ref="auto:P profile frames 1-90")
    kept = [Observation(1.0, "BAA", remark="start checked",
                        ref="reviewed:P profile frames 1-90 [A1]")]
    assert without_superseded([start, finish], kept) == [finish]
    assert without_superseded([start, finish], [], ["auto:P profile frames 1-90 [B1]"]) == [start]


def test_an_edit_renders_the_report_s_observations_again(out: Path) -> None:
    report = out / "report.html"
    before = report.read_text()
    version = read_observations(out)[1]
    edit_observations(out, Edit("add", None, {**GOOD, "remark": "a <b>bold</b> crack"}, version))
    after = report.read_text()
    head, tail = before.index(OBSERVATIONS_BEGIN), before.index(OBSERVATIONS_END)
    assert after.startswith(before[:head])
    assert after.endswith(before[tail + len(OBSERVATIONS_END):])
    section = after[head:after.index(OBSERVATIONS_END)]
    assert "a &lt;b&gt;bold&lt;/b&gt; crack" in section
    observations = parse_observations_csv((out / "observations.csv").read_text())
    assert section.count("<tr>") == len(observations) + 1     # the header row
    assert not any(p.name.endswith(".tmp") for p in out.iterdir())


def test_the_marker_takes_the_fitted_ellipse(out: Path) -> None:
    with ReviewServer(out) as server:
        poses = server.frames.poses
        assert poses.sections and set(poses.sections) <= set(poses.values)
        dataset = server.frames.root
    # A centred, untilted probe in an oval of 30/35 mm whose major axis is at mosaic theta
    # 100 deg, roll 40 deg: a wall point on the major axis is further out than on the
    # circle of the mean radius, so it is seen further from the image centre; one on
    # the minor axis nearer.
    pose = {"frame": "0", "alpha_deg": "0", "beta_deg": "0", "dx_mm": "0", "dy_mm": "0",
            "z_mm": "0", "roll_deg": "40", "radius_mm": "32.5"}
    oval = {"frame": "0", "ovality": "0.15", "min_radius_mm": "30", "max_radius_mm": "35",
            "major_axis_theta_deg": "100"}
    poses = FramePoses.from_rows([pose], [oval])
    section = poses.section(0)
    assert isinstance(section, PipeSection)
    assert section.radius_at(np.radians(60.0)) == pytest.approx(35.0)
    circle = FramePoses.from_rows([pose])
    assert circle.section(0).is_circle
    frames = [SourceFrames(dataset, p, deg_per_px=0.25, mm_per_px=0.135) for p in (poses, circle)]
    centre = np.array(frames[0]._opened().config.camera_model().project(
        np.array([[0.0, 0.0, 1000.0]]))).reshape(2)
    for theta, sign in ((100.0, 1), (10.0, -1)):
        oval_px, circle_px = (np.array(f.point_in_frame(0, 20.0, theta)) for f in frames)
        assert sign * (np.hypot(*(oval_px - centre)) - np.hypot(*(circle_px - centre))) > 2
