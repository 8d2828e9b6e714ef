"""Measurement on the mosaic: defects (holes, spots) with their size in mm, position
along the pipe and clock position, and block statistics of the wall.

May import ``geometry``, ``camera``, ``_runtime``, ``errors``. Must not import
``standards``, ``io``, ``pipeline`` or ``cli``.
"""
