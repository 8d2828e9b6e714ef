"""The pure standards package: clock positions, references, ovality definitions, invert
detection, observation coding and the exchange formats (round trips and a published
EN 13508-2 example)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest

from pipestitch.standards import (
    DWA_CONTINUOUS_MIN_M,
    Observation,
    Survey,
    clock_hhmm,
    clock_hour,
    crown_from_imu,
    crown_from_invert,
    detect_invert,
    observations_from_defects,
    observations_from_profile,
    parse_en13508,
    parse_json,
    parse_observations_csv,
    parse_pacp_csv,
    relative_reference,
    section_figures,
    user_reference,
    write_en13508,
    write_json_text,
    write_observations_csv,
    write_pacp_csv,
)
from pipestitch.standards.observations import ProfileSection

# --- clock positions -------------------------------------------------------------------

@pytest.mark.parametrize(("theta", "hour"), [(270, 12), (0, 3), (90, 6), (180, 9), (300, 1),
                                             (284.9, 12), (285.1, 1), (255.1, 12)])
def test_clock_hour_gravity_frame(theta: float, hour: int) -> None:
    # +y down: crown at 270, 3 o'clock at +x (0), invert at +y (90), left at 180.
    assert clock_hour(theta) == hour


def test_clock_follows_the_crown() -> None:
    assert clock_hour(10.0, crown_theta_deg=10.0) == 12
    assert clock_hour(100.0, crown_theta_deg=10.0) == 3
    assert clock_hhmm(10.0 + 45.0, crown_theta_deg=10.0) == "1:30"


def test_crown_from_imu_recovers_the_offset() -> None:
    # Truth: gravity roll g_k; the mosaic only knows roll relative to frame 0.
    rng = np.random.default_rng(3)
    g = rng.uniform(-40, 40, 20)
    mosaic = {k: float(g[k] - g[0]) for k in range(20)}
    imu = {k: float(g[k]) for k in range(20)}
    ref = crown_from_imu(mosaic, imu)
    assert ref is not None and ref.source == "imu"
    # A wall point at gravity theta t shows at mosaic theta t - g0: the crown (270).
    assert ref.crown_theta_deg == pytest.approx((270 - g[0]) % 360, abs=1e-9)
    assert ref.to_gravity((150 - g[0]) % 360) == pytest.approx(150, abs=1e-9)
    assert crown_from_imu(mosaic, {99: 1.0}) is None


def test_references_name_their_source() -> None:
    assert relative_reference().crown_theta_deg == 270
    assert user_reference(-30).crown_theta_deg == 330
    assert crown_from_invert(100).crown_theta_deg == 280
    assert {r.source for r in (relative_reference(), user_reference(0), crown_from_invert(0))} \
        == {"relative", "user (--crown-deg)", "invert-detected"}


# --- ovality ---------------------------------------------------------------------------

def test_section_figures_by_definition() -> None:
    # An ellipse with semi-axes 33 and 32 mm: mean ID taken as 65 mm, nominal 66 mm.
    f = section_figures(65.0, 64.0, 66.0, 66.0)
    assert f.f1216_mean_min_pct == pytest.approx(100 * 1 / 65)
    assert f.f1216_max_mean_pct == pytest.approx(100 * 1 / 65)
    assert f.range_nominal_pct == pytest.approx(100 * 2 / 66)
    assert f.deflection_pct == pytest.approx(100 * 2 / 66)


def test_circle_model_reports_nothing() -> None:
    f = section_figures(65.0, 65.0, 65.0, 65.0, measured=False)
    assert all(math.isnan(v) for v in (f.f1216_mean_min_pct, f.f1216_max_mean_pct,
                                       f.range_nominal_pct, f.deflection_pct))
    f = section_figures(65.0, math.nan, math.nan, 65.0)
    assert math.isnan(f.deflection_pct)


# --- invert detection --------------------------------------------------------------------

def _wall(rows: int = 720, cols: int = 300, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return (100 + 8 * rng.standard_normal((rows, cols))).astype(np.float32)


@pytest.mark.parametrize("centre", [90.0, 5.0, 200.0])
def test_invert_band_found_where_drawn(centre: float) -> None:
    img = _wall()
    deg_per_px = 0.5
    theta = np.arange(img.shape[0]) * deg_per_px
    inside = np.abs((theta - centre + 180) % 360 - 180) < 30     # 60 deg wide, wraps at 5
    img[inside] *= 0.6                                             # sediment: 40 % darker
    img[:, :20] = np.nan                                           # unseen start
    band = detect_invert(img, deg_per_px)
    assert band is not None
    # Band edges are blurred by the 3 deg smoothing only: centre within 1 deg.
    assert abs((band.theta_deg - centre + 180) % 360 - 180) < 1.0
    assert 50 < band.width_deg < 70


def test_invert_on_a_long_mosaic_reads_a_bounded_sample_of_columns(monkeypatch) -> None:
    """A long run's overview (~10^4 columns) is read at MAX_COLUMNS evenly spaced
    columns: the band is the one the whole image gives, a band on only part of the run
    is still refused, and the working memory does not grow with the length."""
    import tracemalloc

    from pipestitch.standards import invert

    monkeypatch.setattr(invert, "MAX_COLUMNS", 400)
    img = _wall(rows=360, cols=3000, seed=2)
    theta = np.arange(img.shape[0]) * 1.0
    img[np.abs(theta - 250) < 25] *= 0.6
    cols = invert.invert_columns(img.shape[1])
    assert cols.size == 400 and cols[0] == 0 and cols[-1] == 2999 and np.all(np.diff(cols) > 0)
    sampled = detect_invert(img, 1.0)
    monkeypatch.setattr(invert, "MAX_COLUMNS", 10_000)
    whole = detect_invert(img, 1.0)
    assert sampled is not None and whole is not None
    assert abs(sampled.theta_deg - whole.theta_deg) < 0.5
    assert abs(sampled.width_deg - whole.width_deg) <= 1.0
    monkeypatch.setattr(invert, "MAX_COLUMNS", 400)
    partial = img.copy()
    partial[:, 1000:] = _wall(rows=360, cols=2000, seed=3)
    assert detect_invert(partial, 1.0) is None       # in a third of the run only
    peaks = []
    for n in (3000, 12000):
        wide = np.tile(img, (1, n // 3000))
        tracemalloc.start()
        detect_invert(wide, 1.0)
        peaks.append(tracemalloc.get_traced_memory()[1])
        tracemalloc.stop()
    assert peaks[1] < 1.2 * peaks[0]


@pytest.mark.parametrize("amplitude", [0.2, 0.5])
def test_a_smooth_swell_of_brightness_is_no_invert(amplitude: float) -> None:
    # The LEDs light the wall the probe is nearer to more: a cosine around the pipe,
    # persistent along the run and wider than any threshold, but with no edge.
    img = _wall()
    theta = np.arange(img.shape[0]) * 0.5
    swell = 1 + amplitude * np.cos(np.deg2rad(theta - 40))
    assert detect_invert(img * swell[:, None], 0.5) is None
    inside = np.abs((theta - 200 + 180) % 360 - 180) < 30
    img[inside] *= 0.6                                       # a real band beside it
    band = detect_invert(img * (1 + 0.1 * np.cos(np.deg2rad(theta - 40)))[:, None], 0.5)
    assert band is not None and abs(band.theta_deg - 200) < 2.0


def test_no_band_no_invert() -> None:
    img = _wall()
    assert detect_invert(img, 0.5) is None
    img[100:110, 140:150] = 5.0            # a hole is not a band
    img[300:310, :] = 20.0                 # a 5 deg persistent strip (an arm's shadow) is not
    assert detect_invert(img, 0.5) is None
    img = _wall()
    img[200:300, :100] *= 0.5               # dark patch over a third of the run only
    assert detect_invert(img, 0.5) is None


# --- observations ------------------------------------------------------------------------

@dataclass
class _Defect:
    kind: str
    z_mm: float
    theta_deg: float
    diameter_mm: float
    area_mm2: float
    z_min_mm: float
    z_max_mm: float
    theta_min_deg: float
    theta_max_deg: float
    partial: bool = False


def test_defects_become_coded_observations() -> None:
    defects = [_Defect("hole", 120.0, 150.0, 6.0, 28.3, 117.0, 123.0, 145.0, 155.0),
               _Defect("spot", 520.0, 350.0, 40.0, 900.0, 300.0, 740.0, 330.0, 20.0, True)]
    obs = observations_from_defects(defects, relative_reference(), start_z_mm=20.0,
                                    frame_for=lambda z: 7,
                                    continuous_min_m=DWA_CONTINUOUS_MIN_M)
    hole, start, finish = obs
    # BAC B is quantified by the hole's length along the pipe: 123 - 117 = 6 mm.
    assert (hole.code, hole.char1, hole.quant1) == ("BAC", "B", 6)
    assert hole.distance_m == 0.10 and hole.clock_from == 8 and hole.clock_to is None
    assert hole.ref.startswith("auto:D1") and "frame 00007" in hole.ref
    # 440 mm long, over DWA's 0.3 m: a continuous pair at its ends, EN markers A1/B1;
    # 50 deg wide across 0: from 2 to 4 o'clock.
    assert (start.continuous, finish.continuous) == ("A1", "B1")
    assert (start.distance_m, finish.distance_m) == (0.28, 0.72)
    assert (start.clock_from, start.clock_to) == (2, 4)
    assert (start.code, start.char1) == ("BBB", "Z") and "lower bound" in start.remark
    # EN 13508-2's own threshold (1 m, the default): one observation at the centre.
    en = observations_from_defects(defects, relative_reference(), start_z_mm=20.0)
    assert [(o.distance_m, o.continuous) for o in en] == [(0.10, ""), (0.50, "")]
    # Spots coded as surface damage carry both characterisations (Z other, E cause
    # not determinable).
    damage = observations_from_defects(defects, relative_reference(), start_z_mm=20.0,
                                       spots="surface-damage")
    assert (damage[1].code, damage[1].char1, damage[1].char2) == ("BAF", "Z", "E")
    with pytest.raises(ValueError, match="spots"):
        observations_from_defects(defects, relative_reference(), 20.0, spots="stain")


def _section(frame: int, z_mm: float, q_pct: float, deflection: float) -> ProfileSection:
    from pipestitch.standards.ovality import SectionFigures
    return ProfileSection(frame, z_mm, 65.0, math.nan, math.nan,
                          SectionFigures(q_pct, q_pct, math.nan, deflection))


def test_profile_stretches_become_deformations() -> None:
    sections = ([_section(k, 10.0 * k, 0.2, 0.3) for k in range(5)]
                + [_section(k, 10.0 * k, 2.5, 2.6 + k / 100) for k in range(5, 50)]
                + [_section(50, 500.0, math.nan, math.nan), _section(51, 510.0, 3.0, 3.1)])
    obs = observations_from_profile(sections, start_z_mm=0.0, threshold_pct=1.0,
                                    continuous_min_m=DWA_CONTINUOUS_MIN_M)
    assert [o.continuous for o in obs] == ["A1", "B1", ""]
    assert (obs[0].distance_m, obs[1].distance_m, obs[2].distance_m) == (0.05, 0.49, 0.51)
    assert obs[0].code == "BAA" and obs[0].quant1 == 3          # worst deflection 3.09 %
    # No roll reference: characterisation 1 (vertical/horizontal) is left empty, and
    # the remark says it is unknown.
    assert obs[0].char1 == "" and "unknown" in obs[0].remark
    # 0.44 m is shorter than EN's 1 m: one observation at the worst section.
    assert [o.continuous for o in observations_from_profile(sections, 0.0)] == ["", ""]
    # Circle-model sections (NaN) are never flagged.
    assert observations_from_profile([_section(0, 0.0, math.nan, math.nan)], 0.0) == []


# --- exchange formats ----------------------------------------------------------------------

SURVEY = Survey("pipe 7; east", "2026-11-23", "14:30", 12.5, 65, "imu")
OBS = [
    Observation(0.03, "BAC", "B", quant1=6, remark='hole; "6 mm", area 28 mm2', clock_from=8,
                ref="auto:D1 mosaic z=19.8mm frame 00003"),
    Observation(0.28, "BAF", "Z", quant1=40, quant2=12, remark="spot, 2 to 4", clock_from=2,
                clock_to=4, continuous="S01", ref="auto:D2"),
    Observation(0.72, "BAF", "Z", quant1=40, remark="spot", clock_from=2, clock_to=4,
                continuous="F01", ref="auto:D2"),
    Observation(1.5, "BAA", quant1=3, remark="out of round, axis not measured"),
    Observation(2.0, "BDB", remark="user note, no clock", ref="my photo 12"),
]


def test_en13508_round_trip() -> None:
    text = write_en13508([(SURVEY, OBS)])
    assert text.startswith("#A1=ISO-8859-1\n") and "#C=I;A;B;C;D;E;F;G;H;J;M\n" in text
    [(survey, obs)] = parse_en13508(text)
    assert survey == SURVEY and obs == OBS


def test_pacp_csv_round_trip() -> None:
    text = write_pacp_csv(OBS)
    assert text.splitlines()[1].split(",")[:2] == ["0.03", "H"]
    assert parse_pacp_csv(text) == OBS


def test_json_and_observations_csv_round_trip() -> None:
    survey, obs = parse_json(write_json_text(SURVEY, OBS, {"sections": [{"x": math.nan}]}))
    assert survey == SURVEY and obs == OBS
    assert parse_observations_csv(write_observations_csv(OBS)) == OBS


def test_parsers_name_the_bad_line() -> None:
    text = write_observations_csv(OBS).replace("0.72,BAF", "0.72,B-F")
    with pytest.raises(ValueError, match="line 4: code"):
        parse_observations_csv(text)
    with pytest.raises(ValueError, match="clock_from: expected an hour"):
        parse_observations_csv("distance_m,code,clock_from\n1.0,BAC,13\n")
    en = write_en13508([(SURVEY, OBS)]).replace("#Z\n", "")
    with pytest.raises(ValueError, match="not closed by #Z"):
        parse_en13508(en)


# The first inspection of the example exchange file shipped with the R package
# kwb.en13508.2 (KWB-R/kwb.en13508.2, inst/extdata/example_13508_2.txt, MIT licence,
# Copyright (c) 2018 Kompetenzzentrum Wasser Berlin gGmbH), first lines of its #C block.
# A German-language file: comma separator, continuous codes A<n>/B<n> (Anfang/Ende),
# field letters in another order, fields we do not use (N video, K joint).
KWB_EXAMPLE = """#A1=ISO-8859-1
#A2=de
#A3=,
#A4=.
#A5="
#A6=2010
#B01=ACC,ACB,ABC,ABA,ABQ,AAD,AAB,AAK,AAF,ABF,ABG,ABH,AAA
400,400,A,EN 13508-2:2003+A1:2011,23.5,6,2925,A,2925,2007-07-19,09:05,Mr. Clean/Mrs. Perfect,1
#C=I,N,A,B,C,D,G,H,K,F,M,J
0,,BCD,X,P,2925,,,,,,
0.5,,BAC,B,,59,12,12,A,,4,
3.4,,BAB,A,A,1,12,,A,[Chr1 Y->A] [Chr2 Y->A],,
4.4,,BAB,B,A,2,6,,,[Chr1 Y->B],,A2
5.1,,BAB,B,A,2,6,,,[Chr1 Y->B],,B2
#Z
"""


def test_published_en13508_example_parses() -> None:
    [(survey, obs)] = parse_en13508(KWB_EXAMPLE)
    assert survey.pipe_ref == "1" and survey.standard == "EN 13508-2:2003+A1:2011"
    assert survey.length_m == 23.5 and survey.nominal_diameter_mm == 400
    assert [o.distance_m for o in obs] == [0.0, 0.5, 3.4, 4.4, 5.1]
    assert [o.code for o in obs] == ["BCD", "BAC", "BAB", "BAB", "BAB"]
    assert (obs[1].char1, obs[1].quant1, obs[1].clock_from, obs[1].clock_to) == ("B", 59, 12, 12)
    assert obs[1].ref == "4"                                    # M, photograph reference
    assert obs[2].remark == "[Chr1 Y->A] [Chr2 Y->A]"
    assert (obs[3].continuous, obs[4].continuous) == ("A2", "B2")
    # And what we parsed writes back to the same records in our own layout.
    assert parse_en13508(write_en13508([(survey, obs)])) == [(survey, obs)]
