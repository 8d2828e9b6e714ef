"""The mosaic stage: LED frames -> wall strips as seen from the pipe axis -> registered
and refined frame positions -> one blended, unrolled wall image.

``unwrap`` re-renders a frame on the wall grid, ``occluders`` finds what never shows
the wall, ``photometric`` scores the two mirror hypotheses on the LED frames,
``register`` measures axial shift and roll between strips and solves them globally,
``refine`` corrects poses from the strips' local warps, ``blend`` shades and blends
strips into the canvas; compiled loops lie beside their one caller (``_*_kernels``).

May import: ``camera``, ``geometry``, ``pose`` (the fit result type), ``_runtime``,
``errors``. Must not import ``io``, ``pipeline``, ``cli``, ``simulate``, ``measure``.
"""
