"""The floor of pedrl's layering: what every layer shares, importing nothing else of pedrl (nor Hydra).

- :mod:`pedrl.common.checks`: one-line checks of user values (``check_integer``, ``check_choice``, ``check_device``,
  ``check_memory``, ...), used from :mod:`pedrl.sim` up to the entry points.
- :mod:`pedrl.common.commands`: what a command line shares: ``CONFIG_DIR``, :func:`~pedrl.common.commands.fail` (one
  line on stderr, exit code 2), and the ``argparse`` parser and types of the ``python -m`` tools. The Hydra entry
  points add their own pieces in :mod:`pedrl.cli`, which nothing below them imports.
- :mod:`pedrl.common.recording`: :class:`~pedrl.common.recording.Recording`, the one type of recorded crowds, which the
  trial writes and the analysis, the evaluation and the validation suite read.
"""
