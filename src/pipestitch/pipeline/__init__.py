"""The passes that chain the stages over a dataset: check, pose, run (register, refine,
stitch, measure, code, report), calibrate, simulate, batch.

May import every stage, ``io``, ``report`` and ``_runtime``. Must not import ``cli``:
the command line is a thin layer above it, and so is :mod:`pipestitch.api`.
"""
