"""Camera calibration from checkerboard views: fit, per-view residuals, bad-view rejection.

One entry point for both models (:func:`calibrate_camera`): fit on all views, then
drop views whose reprojection RMS is far above the others (a misdetected or
blurred board, a board partly beyond the lens' valid range) and fit again, until
no view is rejected. Residuals are always computed through the fitted
:class:`pipestitch.camera` model itself, so the figures reported are those of the
model that is written to probe.toml.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from pipestitch.calibrate.checkerboard import BoardView
from pipestitch.calibrate.fisheye_fit import fit_opencv_fisheye
from pipestitch.calibrate.ocam_fit import fit_ocam
from pipestitch.camera import CameraModel

__all__ = ["CameraCalibration", "ViewResidual", "calibrate_camera", "reprojection"]

MODELS = ("ocam", "opencv_fisheye")


@dataclass(frozen=True)
class ViewResidual:
    """One view's reprojection through the fitted model.

    Attributes
    ----------
    name : str
        The view's image.
    pixels : numpy.ndarray, shape (N, 2)
        Detected corners (col, row).
    residuals : numpy.ndarray, shape (N, 2)
        Projected minus detected (col, row) in px.
    rotation, translation : numpy.ndarray
        ``R_probe_board`` (3, 3) and ``t`` (3,) in mm.
    """

    name: str
    pixels: np.ndarray
    residuals: np.ndarray
    rotation: np.ndarray
    translation: np.ndarray

    @property
    def rms_px(self) -> float:
        """Root-mean-square reprojection error (px, over both coordinates' norm)."""
        return float(np.sqrt(np.mean(np.sum(self.residuals**2, axis=1))))


@dataclass(frozen=True)
class CameraCalibration:
    """Result of :func:`calibrate_camera`.

    Attributes
    ----------
    camera : CameraModel
        The fitted model.
    views : list of ViewResidual
        The views used in the final fit.
    rejected : list of (str, str)
        (view name, reason) of views left out.
    """

    camera: CameraModel
    views: list[ViewResidual]
    rejected: list[tuple[str, str]] = field(default_factory=list)

    @property
    def rms_px(self) -> float:
        """Overall RMS reprojection error over all corners of the used views (px)."""
        res = np.concatenate([v.residuals for v in self.views])
        return float(np.sqrt(np.mean(np.sum(res**2, axis=1))))


def reprojection(camera: CameraModel, view: BoardView, rotation: np.ndarray,
                 translation: np.ndarray) -> ViewResidual:
    """Project a view's board points through ``camera`` at the given pose."""
    projected = camera.project(view.object_mm @ rotation.T + translation)
    return ViewResidual(view.name, view.pixels, projected - view.pixels, rotation, translation)


def _fit(views: Sequence[BoardView], model: str, width: int, height: int
         ) -> tuple[CameraModel, list[ViewResidual]]:
    fit = fit_ocam if model == "ocam" else fit_opencv_fisheye
    camera, poses = fit(views, width, height)
    return camera, [reprojection(camera, v, r, t) for v, (r, t) in zip(views, poses, strict=True)]


def _fit_dropping_failures(views: list[BoardView], model: str, width: int, height: int,
                           min_views: int, rejected: list[tuple[str, str]]
                           ) -> tuple[list[BoardView], CameraModel, list[ViewResidual]]:
    """Fit all views; if the fit fails, add views one at a time, boards nearest the centre first.

    ``cv2.fisheye.calibrate`` cannot initialise a board seen far off axis (its
    normalisation by depth breaks near 90°) and fails as a whole without saying
    which view: the views whose addition makes the fit fail are rejected.
    """
    try:
        return views, *_fit(views, model, width, height)
    except ValueError as exc:
        if len(views) <= min_views:
            raise
        first_error = str(exc)
    centre = np.array([width / 2, height / 2])
    order = sorted(views, key=lambda v: float(np.linalg.norm(v.pixels.mean(axis=0) - centre)))
    kept = order[:min_views]
    for view in order[min_views:]:
        try:
            _fit([*kept, view], model, width, height)
            kept.append(view)
        except ValueError as exc:
            rejected.append((view.name, f"fit fails with this view: {exc}"))
    try:
        return kept, *_fit(kept, model, width, height)
    except ValueError as exc:
        raise ValueError(f"{first_error}; also without the views rejected: {exc}") from exc


def calibrate_camera(views: Sequence[BoardView], *, model: str, width: int, height: int,
                     min_views: int = 3, reject_factor: float = 3.0,
                     reject_floor_px: float = 1.0) -> CameraCalibration:
    """Fit a camera model to checkerboard views and reject bad views.

    Parameters
    ----------
    views : sequence of BoardView
        Detected boards (:func:`pipestitch.calibrate.checkerboard.detect_board`).
    model : {"ocam", "opencv_fisheye"}
        Camera model to fit.
    width, height : int
        Image size in pixels.
    min_views : int
        Fewest views a fit may use (fewer raises ValueError).
    reject_factor, reject_floor_px : float
        A view is rejected when its RMS exceeds ``max(reject_factor × median RMS,
        reject_floor_px)`` (or is not finite); one view at a time, worst first. A view
        rejected so is tried again against the final set of views, and kept if it then
        fits: a view past the lens' range that the fit accepted can spoil another's RMS
        before it is itself left out.

    Returns
    -------
    CameraCalibration

    Raises
    ------
    ValueError
        Unknown model, too few views, or a fit that fails.
    """
    if model not in MODELS:
        raise ValueError(f"model: expected one of {', '.join(MODELS)}, got {model!r}")
    kept = list(views)
    rejected: list[tuple[str, str]] = []
    while True:
        if len(kept) < min_views:
            raise ValueError(f"{len(kept)} usable view(s), at least {min_views} needed")
        kept, camera, residuals = _fit_dropping_failures(kept, model, width, height, min_views,
                                                         rejected)
        worst, rms, limit = _worst_view(residuals, reject_factor, reject_floor_px)
        if rms <= limit or len(kept) <= min_views:
            break
        rejected.append((kept[worst].name, f"reprojection RMS {rms:.2f} px > {limit:.2f} px"))
        del kept[worst]
    by_name = {v.name: v for v in views}
    for name, reason in list(rejected):
        if not reason.startswith("reprojection RMS"):
            continue
        trial = [*kept, by_name[name]]
        try:
            trial_camera, trial_residuals = _fit(trial, model, width, height)
        except ValueError:
            continue
        _, rms, limit = _worst_view(trial_residuals, reject_factor, reject_floor_px)
        if rms <= limit:   # the view was rejected only beside a view since left out
            kept, camera, residuals = trial, trial_camera, trial_residuals
            rejected.remove((name, reason))
    return CameraCalibration(camera, residuals, rejected)


def _worst_view(residuals: list[ViewResidual], reject_factor: float,
                reject_floor_px: float) -> tuple[int, float, float]:
    """(index, RMS) of the view with the largest reprojection RMS (inf if not finite),
    and the rejection limit max(reject_factor × median RMS, reject_floor_px)."""
    rms = np.array([r.rms_px for r in residuals])
    limit = max(reject_factor * float(np.nanmedian(rms)), reject_floor_px)
    bad = np.where(np.isfinite(rms), rms, np.inf)
    worst = int(np.argmax(bad))
    return worst, float(bad[worst]), limit
