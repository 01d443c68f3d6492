"""An estimate is a function of its inputs, not of rounding (docs/design.md §2).

The same trials of the paper's game, at every lambda of its sweep, give the same ``theta_hat``
(to 1e-6) in processes whose BLAS kernels differ (``OPENBLAS_CORETYPE`` changes only the
kernels' rounding), and when the features are perturbed by 1e-12. The ``posterior_mean``
robot's records are bitwise the same whatever the BLAS kernel, whichever of numpy's SIMD
variants are dispatched (``NPY_DISABLE_CPU_FEATURES``), whatever vector width its compiled
loops run in (``NUMBA_CPU_NAME=generic``), and whatever trials share the batch.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from cirl_study.core.trial import play_trials
from cirl_study.features import RBFFeatures
from cirl_study.record import Grid, TrialSpec

SWEEP = (1e-4, 1e-2, 1.0, 1e2, 1e3)


def paper_trials(
    count: int = 4,
    perturbation: float = 0.0,
    sweep: tuple[float, ...] = SWEEP,
    robot: str = "map",
) -> list[TrialSpec]:
    """``count`` draws of the paper's game (10 x 10, 9 steps, K = 10) x both humans x sweep."""
    rng = np.random.default_rng(2016)
    specs = []
    for index in range(count):
        centers = rng.uniform(0, 9, size=(10, 2))
        theta = rng.uniform(-1, 1, size=10)
        centers = centers + perturbation * rng.choice([-1.0, 1.0], size=centers.shape)
        for rationality in sweep:
            for human, eta in (("expert", None), ("best_response", 0.316)):
                specs.append(
                    TrialSpec(
                        trial_id=f"{index}:{human}:{rationality}",
                        run_id="stability",
                        block="lambda_sweep",
                        subject=f"s{index}",
                        human=human,
                        num_features=10,
                        rationality=rationality,
                        eta=eta,
                        seed=index,
                        grid=Grid(width=10, height=10),
                        start=(5, 5),
                        learning_steps=9,
                        deployment_steps=9,
                        features=RBFFeatures(
                            centers=tuple(map(tuple, centers.tolist())), sigma=1.5
                        ),
                        theta=tuple(theta.tolist()),
                        robot=robot,
                    )
                )
    return specs


def estimates(records) -> dict[str, tuple[list[float], bool]]:
    return {r.trial_id: (list(r.theta_hat), r.irl.converged) for r in records}


def posterior_trials() -> list[TrialSpec]:
    """Two draws of the paper's game x both humans x lambda 1, 100, 1000, posterior mean."""
    return paper_trials(2, sweep=(1.0, 1e2, 1e3), robot="posterior_mean")


def bits(records) -> dict[str, list[str]]:
    """Every number of a Monte-Carlo estimate's record, exactly (``float.hex``)."""
    return {
        r.trial_id: [
            *(float(x).hex() for x in (*r.theta_hat, *r.theta_hat_se)),
            float(r.effective_sample_size).hex(),
            float(r.irl.log_likelihood).hex(),
            str(r.irl.iterations),
            str(r.irl.converged),
        ]
        for r in records
    }


_PLAY = (
    "import json, sys; sys.path.insert(0, {tests!r}); import test_core_stability as t; "
    "print(json.dumps(t.{digest}(t.play_trials(t.{trials}()))))"
)


def _play_with(
    coretype: str | None,
    digest: str = "estimates",
    trials: str = "paper_trials",
    disable: tuple[str, ...] = (),
    cache: str | None = None,
) -> dict:
    """Play ``trials()`` in a new process with the BLAS kernel ``coretype`` (None: the
    library's choice) and numpy's SIMD targets ``disable`` turned off; ``digest`` of the records.
    With ``cache`` (a fresh directory), the kernels are compiled there for a generic x86-64
    CPU (``NUMBA_CPU_NAME=generic``: SSE2, two lanes a vector, instead of this CPU's).
    """
    environment = dict(os.environ)
    environment.pop("OPENBLAS_CORETYPE", None)
    environment.pop("NPY_DISABLE_CPU_FEATURES", None)
    if coretype is not None:
        environment["OPENBLAS_CORETYPE"] = coretype
    if disable:
        environment["NPY_DISABLE_CPU_FEATURES"] = " ".join(disable)
    if cache is not None:
        environment.update(NUMBA_CPU_NAME="generic", NUMBA_CACHE_DIR=cache)
    code = _PLAY.format(tests=os.path.dirname(__file__), digest=digest, trials=trials)
    done = subprocess.run(
        [sys.executable, "-c", code], env=environment, capture_output=True, text=True, check=True
    )
    return json.loads(done.stdout)


def _dispatched_targets() -> tuple[str, ...]:
    """numpy's SIMD dispatch targets beyond its baseline that this CPU has."""
    from numpy._core._multiarray_umath import __cpu_dispatch__, __cpu_features__

    return tuple(target for target in __cpu_dispatch__ if __cpu_features__.get(target))


@pytest.mark.skipif(sys.platform != "linux", reason="OPENBLAS_CORETYPE is an OpenBLAS setting")
def test_the_estimates_do_not_depend_on_the_blas_kernels():
    default, prescott = _play_with(None), _play_with("Prescott")
    assert default.keys() == prescott.keys()
    for trial, (theta, converged) in default.items():
        assert converged == prescott[trial][1], trial
        np.testing.assert_allclose(theta, prescott[trial][0], rtol=0, atol=1e-6, err_msg=trial)


@pytest.mark.skipif(sys.platform != "linux", reason="OPENBLAS_CORETYPE is an OpenBLAS setting")
def test_the_posterior_mean_is_bitwise_the_same_on_every_kernel(tmp_path):
    default = _play_with(None, "bits", "posterior_trials")
    assert len(default) == 12
    prescott = _play_with("Prescott", "bits", "posterior_trials")
    narrowed = _play_with(None, "bits", "posterior_trials", disable=_dispatched_targets())
    generic = _play_with(None, "bits", "posterior_trials", cache=str(tmp_path))
    for trial, numbers in default.items():
        assert prescott[trial] == numbers, trial
        assert narrowed[trial] == numbers, trial
        assert generic[trial] == numbers, trial


def test_a_posterior_mean_record_does_not_depend_on_its_batch():
    specs = posterior_trials()
    together = bits(play_trials(specs))
    for spec in specs[::5]:
        assert bits(play_trials([spec])) == {spec.trial_id: together[spec.trial_id]}


def test_certified_estimates_do_not_move_with_the_features_last_bits():
    plain = estimates(play_trials(paper_trials()))
    nudged = estimates(play_trials(paper_trials(perturbation=1e-12)))
    converged = [trial for trial, (_, converged) in plain.items() if converged]
    # Nearly all are converged; the rest lie where the likelihood is flat to rounding.
    assert len(converged) >= 0.9 * len(plain)
    for trial in converged:
        np.testing.assert_allclose(
            plain[trial][0], nudged[trial][0], rtol=0, atol=1e-6, err_msg=trial
        )
