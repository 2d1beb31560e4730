"""The benchmark: jittered starts (seeded, valid, within the jitter, shared by the planners), the
table."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tsrrt_planner.bench import default_models, jittered_problem, main, resolve_scenario, table
from tsrrt_planner.errors import PlannerError
from tsrrt_planner.model_learning import ModelStore


@pytest.fixture(scope="module")
def tset3():
    scenario = resolve_scenario("tset3")
    return scenario, ModelStore.load(default_models(scenario))


def test_a_jittered_start_is_valid_within_the_jitter_and_the_same_for_a_seed(tset3) -> None:
    scenario, models = tset3
    original = np.array([o.pose.as_array() for o in scenario.objects])
    problem = jittered_problem(scenario, models, (0.02, 0.2), seed=3)
    assert problem.state_valid(problem.start)
    offset = problem.start - original
    assert np.abs(offset[:, :2]).max() <= 0.02 and np.abs(offset[:, 2]).max() <= 0.2
    assert np.abs(offset).max() > 0.0
    np.testing.assert_array_equal(
        jittered_problem(scenario, models, (0.02, 0.2), seed=3).start, problem.start)
    assert not np.array_equal(jittered_problem(scenario, models, (0.02, 0.2), seed=4).start,
                              problem.start)


def test_a_jitter_that_leaves_no_valid_start_is_an_error(tset3) -> None:
    scenario, models = tset3
    with pytest.raises(PlannerError, match="no valid start within"):
        jittered_problem(scenario, models, (1.0, 0.0), seed=0)


def test_the_bench_plans_every_planner_from_the_seed_s_jittered_start(tmp_path,
                                                                      tset3) -> None:
    out = tmp_path / "bench.json"
    main(["--scenario", "tset3", "--planners", "tsrrt,greedy", "--seeds", "2",
          "--first-seed", "5", "--budget-s", "0.3", "--lb-starts", "2",
          "--start-jitter", "0.02,0.2", "--json", str(out)])
    report = json.loads(out.read_text())
    assert report["start_jitter"] == [0.02, 0.2]
    starts = {(r["planner"], r["seed"]): r["start_cost"] for r in report["results"]}
    assert sorted(starts) == [("greedy", 5), ("greedy", 6), ("tsrrt", 5), ("tsrrt", 6)]
    for seed in (5, 6):
        assert starts[("tsrrt", seed)] == starts[("greedy", seed)] != report["start_cost"]
    assert starts[("tsrrt", 5)] != starts[("tsrrt", 6)]
    seed_5 = jittered_problem(*tset3, (0.02, 0.2), seed=5)
    assert starts[("tsrrt", 5)] == pytest.approx(seed_5.objective.cost(seed_5.start))


def test_primitives_nothing_learned_covers_are_planned_with_the_push_rule(tmp_path,
                                                                          capsys) -> None:
    """As planner_node plans them: without them, a demo's tset6 models (plate pushes blocked
    while learning) left the bench 63-65 % above the bound; planned as the node does, 3.6-21 %."""
    scenario = resolve_scenario("clean")
    store = ModelStore.load(default_models(scenario))
    for primitive in (3, 4):   # a pair, so that neither is the other's mirror image
        del store.models[("eraser", primitive)]
    partial = tmp_path / "models.yaml"
    store.save(partial)
    out = tmp_path / "bench.json"
    main(["--scenario", "clean", "--planners", "tsrrt", "--seeds", "1", "--budget-s", "0.3",
          "--lb-starts", "2", "--models", str(partial), "--json", str(out)])
    assert "eraser primitive 3, eraser primitive 4: planned with the push rule" in (
        capsys.readouterr().out)
    assert json.loads(out.read_text())["results"][0]["gap_final"] is not None


@pytest.mark.parametrize("value", ["0.02", "a,b", "0.02,-0.1", "nan,0.1"])
def test_a_malformed_jitter_is_refused(value: str) -> None:
    with pytest.raises(SystemExit):
        main(["--scenario", "tset3", "--start-jitter", value])


@pytest.mark.parametrize("arguments", [["--first-seed", "-1"], ["--seeds", "0"]])
def test_a_negative_first_seed_or_no_seeds_is_refused(arguments: list[str], capsys) -> None:
    with pytest.raises(SystemExit):
        main(["--scenario", "tset3", *arguments])
    assert "--seeds must be >= 1, --first-seed >= 0" in capsys.readouterr().err


def _row(planner: str, gap: float | None, cost: float = -1.0) -> dict:
    return {"planner": planner, "seed": 0, "time_to_5pct_s": None, "time_to_1pct_s": None,
            "nodes_to_5pct": None, "nodes_to_1pct": None, "gap_at_1s": gap, "gap_final": gap,
            "nodes_per_s": 10.0, "pushes": 5, "final_cost": cost}


def test_the_table_counts_the_seeds_within_5_and_1_percent() -> None:
    """A bimodal planner (three seeds near the bound, two far off) has a median that says
    nothing of the two; the counts do."""
    rows = [_row("tsrrt", gap) for gap in (0.004, 0.02, 0.03, 0.25, 0.55)]
    header, _, line = (text.split() for text in table(rows, ["tsrrt"]).splitlines())
    assert line[header.index("end<=5%")] == "3/5"
    assert line[header.index("end<=1%")] == "1/5"
    assert line[header.index("gap@end")] == "3.00%"


def test_without_gaps_the_counts_are_not_applicable() -> None:
    """Against a zero optimum (the obstacle task) there is no relative gap."""
    header, _, line = (text.split() for text in
                       table([_row("tsrrt", None, cost=0.002)], ["tsrrt"]).splitlines())
    assert [line[header.index(key)] for key in ("end<=5%", "end<=1%")] == ["n/a", "n/a"]
