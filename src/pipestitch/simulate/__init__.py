"""Synthetic probe runs with ground truth: wall textures, trajectories, rendering of
laser and LED frames, scenarios, and the scoring of a mosaic against the true wall.

May import ``camera`` and ``geometry`` (and ``mosaic.register``'s phase correlation,
for scoring only); must not import ``pose``, ``io``, ``pipeline`` or ``cli``: the
truth it writes never comes from the code it is used to test.
"""
