"""probe.toml as validated pydantic models (SPEC), checked once at the edge.

Unknown keys are rejected (``extra="forbid"``) so a misspelt key is reported
instead of silently ignored. Values must be finite. Building the camera model
from the validated config is :meth:`ProbeConfig.camera_model`.
"""

from __future__ import annotations

import math
from typing import Annotated, Literal

from pydantic import AfterValidator, BaseModel, ConfigDict, Field, model_validator

from pipestitch.camera import CameraModel, OcamModel, OpenCVFisheyeModel
from pipestitch.geometry import BodyEnvelope, PipeSection

__all__ = ["CameraConfig", "LaserConfig", "PipeConfig", "ProbeBodyConfig", "ProbeConfig"]


def _finite(value: float) -> float:
    if not math.isfinite(value):
        raise ValueError(f"must be a finite number, got {value}")
    return value


Finite = Annotated[float, AfterValidator(_finite)]
Positive = Annotated[float, Field(gt=0), AfterValidator(_finite)]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class CameraConfig(_Strict):
    """``[camera]``: an OCamCalib or OpenCV fisheye model and the image size."""

    model: Literal["ocam", "opencv_fisheye"]
    width: Annotated[int, Field(gt=0)]
    height: Annotated[int, Field(gt=0)]
    pol: list[Finite] | None = None
    invpol: list[Finite] | None = None
    center: Annotated[list[Finite], Field(min_length=2, max_length=2)] | None = None
    affine: Annotated[list[Finite], Field(min_length=3, max_length=3)] | None = None
    K: list[list[Finite]] | None = None
    D: Annotated[list[Finite], Field(min_length=4, max_length=4)] | None = None

    @model_validator(mode="after")
    def _fields_of_model(self) -> CameraConfig:
        needed = {"ocam": ("pol", "center"), "opencv_fisheye": ("K", "D")}[self.model]
        missing = [name for name in needed if getattr(self, name) is None]
        if missing:
            raise ValueError(f"camera model {self.model!r} needs {', '.join(missing)}")
        if self.K is not None and (len(self.K) != 3 or any(len(r) != 3 for r in self.K)):
            raise ValueError("K must be a 3 x 3 matrix")
        if self.K is not None and not (self.K[0][0] > 0 and self.K[1][1] > 0):
            raise ValueError(f"K: focal lengths fx, fy must be positive, got {self.K[0][0]}, "
                             f"{self.K[1][1]}")
        return self

    def build(self) -> CameraModel:
        """The camera model this section describes (raises ValueError if invalid)."""
        if self.model == "ocam":
            c, d, e = self.affine or (1.0, 0.0, 0.0)
            return OcamModel(pol=tuple(self.pol), invpol=tuple(self.invpol or ()),
                             center_row=self.center[0], center_col=self.center[1],
                             c=c, d=d, e=e, width=self.width, height=self.height)
        k = self.K
        return OpenCVFisheyeModel(fx=k[0][0], fy=k[1][1], cx=k[0][2], cy=k[1][2], k=tuple(self.D),
                                  width=self.width, height=self.height, skew=k[0][1] / k[0][0])

    @classmethod
    def from_model(cls, cam: CameraModel) -> CameraConfig:
        """The ``[camera]`` section describing ``cam``."""
        if isinstance(cam, OcamModel):
            return cls(model="ocam", width=cam.width, height=cam.height, pol=list(cam.pol),
                       invpol=list(cam.invpol), center=[cam.center_row, cam.center_col],
                       affine=[cam.c, cam.d, cam.e])
        if isinstance(cam, OpenCVFisheyeModel):
            return cls(model="opencv_fisheye", width=cam.width, height=cam.height,
                       K=cam.camera_matrix.tolist(), D=list(cam.k))
        raise TypeError(f"unsupported camera model {type(cam).__name__}")


MAX_LASER_TILT_DEG = 20.0


def _unit_normal(value: list[float] | None) -> list[float] | None:
    """Check a laser-plane normal (3 finite numbers, within 20° of +z) and normalise it."""
    if value is None:
        return None
    if len(value) != 3:
        raise ValueError(f"expected 3 numbers [nx, ny, nz], got {len(value)}")
    norm = math.sqrt(sum(v * v for v in value))
    if norm == 0:
        raise ValueError("must not be the zero vector")
    unit = [v / norm for v in value]
    tilt = math.degrees(math.acos(max(-1.0, min(1.0, unit[2]))))
    if tilt > MAX_LASER_TILT_DEG:
        raise ValueError(f"must be within {MAX_LASER_TILT_DEG:g}° of the optical axis +z, "
                         f"got {tilt:.1f}°")
    return unit


class LaserConfig(_Strict):
    """``[laser]``: the laser plane {p : n·p = d} in the probe frame.

    SPEC's plane is z = d (n = +z). ``normal`` is pipestitch's optional extension
    (docs/calibration.md): a calibrated unit normal, normalised on load.
    """

    plane_distance_mm: Positive
    normal: Annotated[list[Finite] | None, AfterValidator(_unit_normal)] = None

    def plane_normal(self) -> tuple[float, float, float]:
        """The plane's unit normal (SPEC's +z when ``normal`` is absent)."""
        return (0.0, 0.0, 1.0) if self.normal is None else tuple(self.normal)


class ProbeBodyConfig(_Strict):
    """``[probe]`` (optional): the rigid probe body and the occluder mask.

    ``length_mm`` and ``diameter_mm`` come together: a cylinder behind the camera centre
    that must fit in the pipe. Without them there is no body constraint (a point
    probe, as in the reference Table-1 protocol). ``mask`` names a camera-sized grey
    PNG in the dataset, 0 where the camera never sees the wall.
    """

    length_mm: Positive | None = None
    diameter_mm: Positive | None = None
    mask: str | None = None

    @model_validator(mode="after")
    def _body_together(self) -> ProbeBodyConfig:
        if (self.length_mm is None) != (self.diameter_mm is None):
            given = "length_mm" if self.diameter_mm is None else "diameter_mm"
            raise ValueError(f"{given} is given without "
                             f"{'diameter_mm' if given == 'length_mm' else 'length_mm'}: "
                             "the body needs both (or neither, for no body constraint)")
        if self.mask is not None and not self.mask.strip():
            raise ValueError("mask: expected a file name, got an empty string")
        return self

    def envelope(self) -> BodyEnvelope | None:
        """The declared body, or None when probe.toml declares none."""
        if self.length_mm is None or self.diameter_mm is None:
            return None
        return BodyEnvelope(self.length_mm, self.diameter_mm)


class PipeConfig(_Strict):
    """``[pipe]``: nominal pipe."""

    inner_diameter_mm: Positive

    def section(self) -> PipeSection:
        """The nominal circular cross-section."""
        return PipeSection.circle(self.inner_diameter_mm)


class ProbeConfig(_Strict):
    """The whole probe.toml."""

    camera: CameraConfig
    laser: LaserConfig
    probe: ProbeBodyConfig = ProbeBodyConfig()
    pipe: PipeConfig

    @model_validator(mode="after")
    def _body_fits_the_pipe(self) -> ProbeConfig:
        # A body as wide as the pipe could hold no pose at all: one of the two is wrong,
        # and every frame would be flagged for it.
        body = self.probe.diameter_mm
        if body is not None and body >= self.pipe.inner_diameter_mm:
            raise ValueError(f"[probe] diameter_mm = {body:g} does not fit in [pipe] "
                             f"inner_diameter_mm = {self.pipe.inner_diameter_mm:g}")
        return self

    def camera_model(self) -> CameraModel:
        """Build the camera model."""
        return self.camera.build()
