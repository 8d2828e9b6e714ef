"""The self-contained HTML report and the mosaic viewer page, as text.

Pure (no file access): the pipeline writes what these functions return. May import
``measure``, ``standards``, ``geometry``, ``errors``; must not import ``io``,
``pipeline`` or ``cli``.
"""
