"""pipestitch: centralisation and stitching for small-bore pipe inspection probes.

See ``docs/conventions.md`` for frames, units and the pose convention (SPEC).
"""

__version__ = "0.1.0"
