"""``python -m cirl_study``: the ``cirl-study`` command line."""

from cirl_study.cli import console_script

console_script()
