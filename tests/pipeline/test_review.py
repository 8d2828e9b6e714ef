"""The review server: what it refuses (bad input, paths outside OUT, other hosts) and how
an edit lands in observations.csv (other rows byte for byte, atomically, re-exported)."""

from __future__ import annotations

import http.client
import json
import shutil
from pathlib import Path

import pytest
from typer.testing import CliRunner

from pipestitch.cli.app import app
from pipestitch.pipeline.review import (
    Edit,
    EditError,
    edit_observations,
    read_observations,
    validated_observation,
)
from pipestitch.pipeline.review_server import ReviewServer
from pipestitch.standards.observations import parse_observations_csv

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
