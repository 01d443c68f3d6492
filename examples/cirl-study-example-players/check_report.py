"""Check the report of ``three-humans.toml``: ``python check_report.py REPORT_DIR``.

The study's design is this package's players beside the paper's, and the report has what
any study's has: the ANOVA with the three-level human factor corrected for sphericity, every
pairwise comparison, the paper's claims that its cells allow and the others not tested.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path


def main(report: Path) -> None:
    results = json.loads((report / "results.json").read_text(encoding="utf-8"))
    design = results["design"]
    assert design["humans"] == ["expert", "best_response", "first_step_only"], design
    assert design["robots"] == ["map", "theta_zero"] and design["feature_levels"] == [3]
    effects = {row["effect"] for row in results["anova"]}
    assert effects == {"human", "robot", "human:robot"}, effects
    human = next(r for r in results["anova"] if r["effect"] == "human")
    assert human["sphericity"] is not None and human["sphericity"]["gg_epsilon"] <= 1
    pairs = {(r["factor"], r["level_a"], r["level_b"]) for r in results["pairwise"]}
    assert ("human", "expert", "first_step_only") in pairs and (
        "robot",
        "map",
        "theta_zero",
    ) in pairs
    claims = {claim["id"]: claim for claim in results["claims"]}
    assert claims["human_effect"]["tested"] and not claims["interaction_kl_l2"]["tested"]
    assert (report / "cell_means.png").stat().st_size > 0
    print(f"{report}: the example's players were analysed like the paper's")


if __name__ == "__main__":
    main(Path(sys.argv[1]))
