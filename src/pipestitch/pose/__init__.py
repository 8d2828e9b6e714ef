"""The pose stage: a laser frame -> ring points -> both mirror hypotheses of the probe
pose (alpha, beta, dx, dy) -> the run-level choice between them.

``ring`` finds the laser ring, ``fit`` fits a circular pipe section (both hypotheses,
costs, ok flag, reason), ``section`` an oval one, ``ambiguity`` chooses per run; the
compiled loops lie beside the module that calls them (``_ring_kernels``,
``_pair_motion_kernels``, ``_fit_kernels``, ``_section_kernels``).

May import: ``camera``, ``geometry``, ``_runtime``, ``errors``. Must not import ``io``,
``pipeline``, ``cli``, ``simulate`` or the later stages (``mosaic``, ``measure``).
"""
