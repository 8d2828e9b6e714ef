"""``python -m pipestitch.cli``: the same as the ``pipestitch`` command."""

from pipestitch.cli import main

main()
