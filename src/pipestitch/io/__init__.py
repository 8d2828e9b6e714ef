"""Files in and out: the dataset folder and probe.toml (SPEC), images and video,
calibration formats, run outputs, the tiled pyramid; every write atomic.

May import: ``camera``, ``geometry``, ``config``, ``errors``, ``jsonsafe``. Must not
import the stages or ``pipeline``/``cli``; only ``pipeline`` and ``cli`` import it.
"""
