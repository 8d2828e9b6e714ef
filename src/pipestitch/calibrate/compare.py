"""How far two camera models disagree, in pixels, over the image circle.

Every pixel of a grid inside the reference model's image (and within a maximum
incidence angle) is unprojected by the reference and projected by the other
model; the statistics of the pixel differences say how much the two calibrations
differ where it matters. A rotation about the optical axis is a gauge freedom of
a calibration (the views' rolls absorb it: OCamCalib's affine matrix can carry a
small rotation that another fit puts into the extrinsics), so the difference is
also given after removing the best such rotation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize_scalar

from pipestitch.camera import CameraModel, pixel_grid

__all__ = ["ModelDifference", "compare_models"]


@dataclass(frozen=True)
class ModelDifference:
    """Pixel differences between two models over the reference's image circle.

    Attributes
    ----------
    mean_px, max_px : float
        Mean and largest |difference| as fitted.
    mean_aligned_px, max_aligned_px : float
        The same after the best rotation about the optical axis.
    roll_deg : float
        That rotation.
    n_pixels : int
        Grid pixels compared.
    max_incidence_deg : float
        Largest incidence angle compared.
    """

    mean_px: float
    max_px: float
    mean_aligned_px: float
    max_aligned_px: float
    roll_deg: float
    n_pixels: int
    max_incidence_deg: float


def _rot_z(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def compare_models(model: CameraModel, reference: CameraModel, *,
                   max_incidence_deg: float = 90.0, step_px: int = 4) -> ModelDifference:
    """Mean and max |pixel difference| of ``model`` against ``reference``.

    Parameters
    ----------
    model, reference : CameraModel
        Models of the same image size.
    max_incidence_deg : float
        Compare only pixels whose reference ray is at most this far off axis (and
        inside both models' valid range).
    step_px : int
        Grid spacing.

    Returns
    -------
    ModelDifference
    """
    if (model.width, model.height) != (reference.width, reference.height):
        raise ValueError(f"compare_models: image sizes differ ({model.width}x{model.height} vs "
                         f"{reference.width}x{reference.height})")
    px = pixel_grid(reference.width, reference.height)
    grid = px.reshape(reference.height, reference.width, 2)[::step_px, ::step_px].reshape(-1, 2)
    rays = reference.unproject(grid)
    limit = min(np.deg2rad(max_incidence_deg), model.max_incidence_rad,
                reference.max_incidence_rad)
    ok = np.isfinite(rays[:, 2]) & (np.arccos(np.clip(rays[:, 2], -1, 1)) <= limit)
    grid, rays = grid[ok], rays[ok]

    def errors(angle: float) -> np.ndarray:
        return np.linalg.norm(model.project(rays @ _rot_z(angle).T) - grid, axis=1)

    raw = errors(0.0)
    best = minimize_scalar(lambda a: float(np.nanmean(errors(a) ** 2)),
                           bounds=(-0.2, 0.2), method="bounded", options={"xatol": 1e-9})
    aligned = errors(float(best.x))
    return ModelDifference(float(np.nanmean(raw)), float(np.nanmax(raw)),
                           float(np.nanmean(aligned)), float(np.nanmax(aligned)),
                           float(np.rad2deg(best.x)), int(ok.sum()),
                           float(np.rad2deg(limit)))
