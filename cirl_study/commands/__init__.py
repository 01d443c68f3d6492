"""The commands of the ``cirl-study`` command line, one module (and one typer app) each.

:mod:`cirl_study.cli` merges their apps into the ``cirl-study`` application.
"""
