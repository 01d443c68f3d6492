"""The Python API: play a pipeline, load a run's trials, analyse a run, from a script or a
notebook. Each is what the command line does, without its report files:
:func:`run` is ``cirl-study run``, :func:`analyze` the numbers of ``cirl-study analyze``.

Every reader checks the logs as the command line does (every CRC, the schema, every record,
that every file and record belongs to the one run); bad input raises
:class:`cirl_study.errors.UserError` with a one-line message.

Examples:
    Play the smoke pipeline (82 trials on a 5 x 5 grid, a few seconds), load its trials and
    analyse them:

    >>> import tempfile
    >>> from pathlib import Path
    >>> import cirl_study
    >>> out = cirl_study.run("smoke", Path(tempfile.mkdtemp()) / "smoke")
    >>> trials = cirl_study.load_trials(out)
    >>> len(trials), sorted(trials["human"].unique()), sorted(trials["block"].unique())
    (82, ['best_response', 'expert'], ['eta_cv', 'lambda_sweep', 'main'])
    >>> main = trials[trials["block"] == "main"]
    >>> main.groupby(["num_features", "human"])["regret"].count().tolist()
    [4, 4, 4, 4]
    >>> results = cirl_study.analyze(out)
    >>> results.design.humans, results.design.robots
    (['expert', 'best_response'], ['map'])
    >>> [row.effect for row in results.anova if row.measure == "regret"]
    ['num_features', 'human', 'human:num_features']
    >>> claim = next(c for c in results.claims if c.id == "lambda_intermediate")
    >>> claim.tested, type(claim.reproduced).__name__
    (True, 'bool')

    Every table of the results (``results.anova``, ``results.cells``, ``results.claims``, a
    multiverse's ``universes``, ...) is a list of typed rows whose ``to_frame()`` gives it as a
    pandas DataFrame, a column per field and a nested record's fields flattened (as pingouin's
    tests return theirs; ``pd.DataFrame(results.anova)`` would make one column of row objects):

    >>> anova = results.anova.to_frame()
    >>> anova[anova["measure"] == "regret"][["effect", "df1", "df2"]].to_numpy().tolist()
    [['num_features', 1, 6], ['human', 1, 6], ['human:num_features', 1, 6]]
    >>> {"F", "p", "log10_p", "sphericity_gg_p"} <= set(anova.columns)
    True
    >>> results.cells.filter(lambda row: row.measure == "kl").to_frame().shape
    (4, 10)
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import pandas as pd

    from cirl_study.analysis.results.types import MultiverseResults, StudyResults


def run(
    pipeline: str | os.PathLike[str], out: str | os.PathLike[str], workers: int | None = None
) -> Path:
    """Play (or resume) every trial of ``pipeline`` into the run directory ``out``.

    Args:
        pipeline: a pipeline file, or the name of a shipped one (``paper``, ``smoke``, ...).
        out: the run directory: created, or resumed when it holds a run of the same pipeline.
        workers: processes of the local pool (default: every core this process may use, as
            ``cirl-study run``); 1 plays in this process. The numbers do not depend on it.

    Returns:
        ``out``, as a path.
    """
    from cirl_study.study.engines import make_engine
    from cirl_study.study.pipeline_file import load_pipeline, resolve_pipeline
    from cirl_study.study.runner import run_pipeline

    target = Path(out)
    engine = make_engine("local", workers, None)
    run_pipeline(load_pipeline(resolve_pipeline(os.fspath(pipeline))), target, engine)
    return target


def load_trials(run_dir: str | os.PathLike[str]) -> pd.DataFrame:
    """The tidy trial table of a run: one row per trial, its identity, its measures and
    whether its robot's estimate met its stopping rule.

    The columns are those of ``trials.csv`` (``docs/pipelines.md``, *The trial table*):
    ``trial_id, run_id, universe, block, subject, human, robot, num_features, rationality,
    eta, seed`` (then ``task, participant, condition`` in a run with participants), a column
    per registered measure
    (:data:`cirl_study.measure_registry.MEASURES`: ``regret, kl, reward_l2,
    regret_under_estimate, ...``; NaN where a trial has no value of it), ``converged`` and
    ``file``, the name of the MCAP log file in ``run_dir`` that holds the trial's record (to
    open one trial in Foxglove, say); rows in a fixed order whatever the order of the logs.
    The run may be incomplete: it holds what the logs hold.
    """
    from cirl_study.analysis.table import trial_table
    from cirl_study.logs.reader import read_run
    from cirl_study.study.pipeline_file import pipelines_in

    return trial_table(read_run(Path(run_dir), pipelines_in(Path(run_dir))).rows)


def analyze(
    run_dir: str | os.PathLike[str], partial: bool = False
) -> StudyResults | MultiverseResults:
    """Every number of the report of a run, as typed results
    (:mod:`cirl_study.analysis.results.types`): what ``cirl-study analyze`` writes to
    ``results.json``, without writing anything.

    Args:
        run_dir: the run directory.
        partial: analyse an incomplete or damaged run (main-block subjects that lack a cell
            are left out), as ``--partial``.

    Raises:
        UserError: the run is incomplete (without ``partial``), holds a foreign trial, or its
            design cannot be analysed.
    """
    from cirl_study.analysis.reading import read_for_analysis

    analysed = read_for_analysis(Path(run_dir), partial=partial)
    if analysed.pipeline.multiverse is not None:
        from cirl_study.analysis.multiverse.results import analyse_multiverse

        return analyse_multiverse(analysed.trials, analysed.pipeline, run_id=analysed.run_id)
    from cirl_study.analysis.results.study import analyse, with_claims
    from cirl_study.analysis.results.theory_claims import theory_claims
    from cirl_study.analysis.table import check_design

    check_design(analysed.trials)
    return with_claims(
        analyse(analysed.trials, analysed.pipeline),
        run_id=analysed.run_id,
        partial=analysed.partial,
        theory=theory_claims(),
    )
