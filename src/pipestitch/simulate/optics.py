"""The simulated probe's optics and sensor: a plain record, importable without the
renderer (scenarios are listed by the command line before anything is rendered)."""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["Optics"]


@dataclass(frozen=True)
class Optics:
    """Physical parameters of the simulated probe's optics and sensor."""

    fov_deg: float = 185.0               # lens image circle (full angle)
    mirror_radius_mm: float = 6.0        # mirror assembly seen around the optical axis
    arm_azimuth_deg: float = 90.0        # image azimuth of the laser holder arm (0 = +col)
    arm_width_deg: float = 7.0           # angular width of the arm's shadow
    laser_sigma_mm: float = 0.22         # Gaussian half-width of the laser sheet on the wall
    laser_peak: float = 0.8              # ring brightness (fraction of full scale)
    laser_background: float = 0.015      # ambient light in the laser frame
    speckle: float = 0.12                # relative speckle of the laser line
    led_gain: float = 1.8                # exposure of the LED frame
    vignetting: float = 0.35             # relative brightness loss at the image circle
    full_well_e: float = 9000.0          # electrons at full scale (shot noise)
    read_noise: float = 1.2 / 255        # read noise, fraction of full scale
    bit_depth: int = 8                   # 8 or 16
    colour: bool = False                 # write BGR frames (red laser, warm LEDs)
    glints: int = 0                      # specular blobs per laser frame
    partial_ring_deg: float = 0.0        # width of a ring sector the laser misses
    # Brightness of the arm and the mirror assembly in the LED frames (fraction of full
    # scale at the image centre, rising outward to 1.6x at the image circle, as a metal
    # part lit by the LEDs is): 0 renders them black (a shadow).
    occluder_level: float = 0.0
    # Auto exposure: the LED frames of every other block of ``exposure_block`` pairs are
    # exposed ``exposure_step`` brighter (0: one exposure for the whole run).
    exposure_step: float = 0.0
    exposure_block: int = 8

    def exposure(self, index: int) -> float:
        """Relative exposure of pair ``index``'s LED frame."""
        return 1.0 + self.exposure_step * ((index // max(1, self.exposure_block)) % 2)
