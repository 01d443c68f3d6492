"""``python -m cirl_study``: the ``cirl-study`` command line."""

from cirl_study.cli import app

app(prog_name="cirl-study")
