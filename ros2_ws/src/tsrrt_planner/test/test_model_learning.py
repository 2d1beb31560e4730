"""Eq. 9 statistics, stopping rules, LEARN_MODEL (Fig. 2) and the model file."""

from __future__ import annotations

import os

import numpy as np
import pytest
import yaml

from tsrrt_common.geometry import Pose2D
from tsrrt_common.scenario import load_scenario
from tsrrt_planner.errors import ModelError, ModelFileError
from tsrrt_planner.model_learning import (
    LEARN_MODEL,
    ConfidenceStoppingRule,
    DisplacementStats,
    ForwardModel,
    ModelStore,
    PaperStoppingRule,
    mirrored,
)
from tsrrt_planner.push_rule import (
    SimulatedPusher,
    learn_all,
    plausible_displacement,
    plausible_spread,
    rule_model,
)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_eq9_matches_numpy_mean_and_variance(seed):
    rng = np.random.default_rng(seed)
    samples = rng.normal([0.05, 0.002, 0.3], [0.004, 0.002, 0.05], (57, 3)) + 1e3 * (seed == 2)
    statistics = DisplacementStats()
    for sample in samples:
        statistics.update(sample)
    np.testing.assert_allclose(statistics.mean, samples.mean(axis=0), rtol=1e-12)
    np.testing.assert_allclose(statistics.variance, samples.var(axis=0), rtol=1e-9)
    np.testing.assert_allclose(statistics.sample_variance, samples.var(axis=0, ddof=1), rtol=1e-9)


def test_non_finite_displacement_is_rejected():
    with pytest.raises(ModelError, match="finite"):
        DisplacementStats().update([np.nan, 0.0, 0.0])


def stats_of(samples) -> DisplacementStats:
    statistics = DisplacementStats()
    for sample in samples:
        statistics.update(sample)
    return statistics


def test_paper_rule_reads_sigma_ref_in_cm_and_degrees():
    rule = PaperStoppingRule(max_trials=100)
    # sigma = 5 mm (0.25 cm^2 < 0.4) and 0.5 deg: done
    calm = stats_of([[0.05 + d, 0.0, np.deg2rad(d * 100)] for d in (-0.005, 0.005)])
    assert rule.done(calm)
    # sigma = 8 mm: 0.64 cm^2 > 0.4, keeps trying
    noisy = stats_of([[0.05 + d, 0.0, 0.0] for d in (-0.008, 0.008)])
    assert not rule.done(noisy)
    assert not rule.done(stats_of([[0.05, 0.0, 0.0]]))  # one sample has no variance yet


def test_confidence_rule_stops_when_the_mean_is_known():
    rule = ConfidenceStoppingRule(min_trials=3, max_trials=50)
    rng = np.random.default_rng(0)
    statistics = DisplacementStats()
    while not rule.done(statistics):
        statistics.update(rng.normal([0.05, 0, 0], [0.005, 0.002, 0.01]))
    assert 3 <= statistics.count < 50
    assert np.all(statistics.mean_half_width() <= [0.003, 0.003, np.deg2rad(1.0)])


def test_rules_stop_at_max_trials():
    statistics = stats_of(np.random.default_rng(1).normal(0, 1.0, (10, 3)))
    assert PaperStoppingRule(max_trials=10).done(statistics)
    assert ConfidenceStoppingRule(max_trials=10).done(statistics)
    with pytest.raises(ModelError):
        ConfidenceStoppingRule(min_trials=5, max_trials=4)


def test_learn_model_recovers_the_pushing_rule():
    scenario = load_scenario("clean")
    remote = scenario.object("remote")
    pusher = SimulatedPusher(scenario.objects, seed=3)
    models, pose = LEARN_MODEL("remote", [1, 2, 3, 4, 5, 6], remote.pose, pusher.apply_action)
    assert set(models) == {1, 2, 3, 4, 5, 6}
    assert pose == pusher.poses["remote"] and pose != remote.pose
    for primitive, model in models.items():
        expected = plausible_displacement(remote, primitive, 0.05)
        tolerance = 3 * np.sqrt(model.variance / model.count) + 1e-9
        assert np.all(np.abs(model.mean - expected) <= tolerance)


def test_learn_model_uses_apply_action_until_rule_is_done():
    calls = []

    def apply_action(object_id, primitive, length):
        calls.append((object_id, primitive, length))
        return np.array([0.04, 0.0, 0.0]), Pose2D(0.0, 0.0, 0.0)

    models, _ = LEARN_MODEL("o", [1, 3], Pose2D(0, 0, 0), apply_action,
                            PaperStoppingRule(min_trials=4), push_length=0.03)
    assert calls == [("o", 1, 0.03)] * 4 + [("o", 3, 0.03)] * 4
    assert models[1].count == 4 and models[1].push_length == 0.03


def test_prediction_scales_linearly_with_push_length():
    model = ForwardModel("o", 1, 0.05, 5, np.array([0.045, 0.002, 0.01]), np.zeros(3))
    np.testing.assert_allclose(model.predict(0.02), [0.018, 0.0008, 0.004])
    with pytest.raises(ModelError, match="outside"):
        model.predict(0.5)


@pytest.fixture
def store() -> ModelStore:
    return learn_all(load_scenario("tset3").objects, seed=1)


def test_model_file_round_trip(tmp_path, store):
    path = tmp_path / "models.yaml"
    store.save(path)
    loaded = ModelStore.load(path)
    assert loaded.classes == store.classes
    assert set(loaded.models) == set(store.models)
    for key, model in store.models.items():
        other = loaded.models[key]
        assert other.count == model.count and other.push_length == model.push_length
        np.testing.assert_allclose(other.mean, model.mean, rtol=1e-15)
        np.testing.assert_allclose(other.m2, model.m2, rtol=1e-15)
    scenario = load_scenario("tset3")
    loaded.check_covers([(o.id, o.object_class, o.shape) for o in scenario.objects])


def test_atomic_write_leaves_old_file_when_writing_fails(tmp_path, store, monkeypatch):
    path = tmp_path / "models.yaml"
    store.save(path)
    before = path.read_text()

    def broken_replace(src, dst):
        raise OSError("disk full")

    monkeypatch.setattr(os, "replace", broken_replace)
    with pytest.raises(OSError, match="disk full"):
        ModelStore([next(iter(store.models.values()))]).save(path)
    assert path.read_text() == before
    assert [p.name for p in tmp_path.iterdir()] == ["models.yaml"]  # no temp file left


@pytest.mark.parametrize("mutate,message", [
    (lambda d: "not: [valid", "not valid YAML"),
    (lambda d: {**d, "version": 7}, "unsupported version 7"),
    (lambda d: {**d, "format": "other"}, "format"),
    (lambda d: {**d, "objects": {}}, "objects"),
])
def test_corrupt_files_raise_and_are_left_untouched(tmp_path, store, mutate, message):
    path = tmp_path / "models.yaml"
    mutated = mutate(store.to_document())
    text = mutated if isinstance(mutated, str) else yaml.safe_dump(mutated)
    path.write_text(text)
    with pytest.raises(ModelFileError, match=message):
        ModelStore.load(path)
    assert path.read_text() == text


@pytest.mark.parametrize("field,value,message", [
    ("count", 0, "count"), ("mean", [0.0, 1.0], "mean"), ("m2", [-1.0, 0.0, 0.0], "negative"),
    ("push_length", 2.0, "push_length"), ("mean", [0.0, float("nan"), 0.0], "mean")])
def test_bad_model_fields_are_named(tmp_path, store, field, value, message):
    document = store.to_document()
    first = next(iter(document["objects"].values()))["primitives"]
    next(iter(first.values()))[field] = value
    path = tmp_path / "m.yaml"
    path.write_text(yaml.safe_dump(document))
    with pytest.raises(ModelFileError, match=message):
        ModelStore.load(path)


def test_a_push_cap_survives_the_model_file_and_only_ever_lowers(tmp_path, store):
    assert store.cap_push("plate_1", 0.05)
    assert not store.cap_push("plate_1", 0.08)      # a longer cap says nothing new
    assert store.cap_push("plate_1", 0.04)
    path = tmp_path / "models.yaml"
    store.save(path)
    assert ModelStore.load(path).push_caps == {"plate_1": 0.04}


@pytest.mark.parametrize("value,message", [
    (0.5, r"objects.plate_1.longest_push: expected a length in"),
    (True, r"objects.plate_1.longest_push: expected a length in"),
    ("5 cm", r"objects.plate_1.longest_push: expected a length in")])
def test_a_bad_push_cap_is_named(tmp_path, store, value, message):
    document = store.to_document()
    document["objects"]["plate_1"]["longest_push"] = value
    path = tmp_path / "m.yaml"
    path.write_text(yaml.safe_dump(document))
    with pytest.raises(ModelFileError, match=message):
        ModelStore.load(path)


def test_an_unknown_object_field_is_named(tmp_path, store):
    document = store.to_document()
    document["objects"]["plate_1"]["longest"] = 0.05
    path = tmp_path / "m.yaml"
    path.write_text(yaml.safe_dump(document))
    with pytest.raises(ModelFileError, match="objects.plate_1: expected the fields 'class' and "
                                             "'primitives', and optionally 'longest_push'"):
        ModelStore.load(path)


def test_mismatched_models_are_an_error(store):
    scenario = load_scenario("tset6")
    with pytest.raises(ModelFileError, match="plate_3: no models"):
        store.check_covers([(o.id, o.object_class, o.shape) for o in scenario.objects])
    with pytest.raises(ModelFileError, match="models are for class 'plate'"):
        store.check_covers([("plate_1", "platter", "box")])


def test_a_primitive_without_a_model_is_unavailable_not_an_error(store):
    partial = ModelStore([m for (o, p), m in store.models.items() if (o, p) != ("plate_1", 3)],
                         store.classes)
    objects = [("plate_1", "plate", "cylinder"), ("plate_2", "plate", "cylinder")]
    with pytest.raises(ModelFileError, match=r"plate_1: no model for primitives \[3\]"):
        partial.check_covers(objects)
    partial.check_covers(objects, every_primitive=False)
    rates, available = partial.rate_table(["plate_1", "plate_2"], ["cylinder", "cylinder"])
    assert available.tolist() == [[True, True, False, True, False, False],
                                  [True, True, True, True, False, False]]
    assert not rates[0, 2].any()


def eraser_model(primitive, mean, count=3):
    return ForwardModel("eraser", primitive, 0.05, count, np.array(mean), np.full(3, 1e-6))


@pytest.mark.parametrize(("primitive", "partner", "partner_mean", "mean"), [
    (2, 1, [0.049, 0.002, -0.01], [-0.049, 0.002, 0.01]),       # across the object's y axis
    (4, 3, [-0.001, 0.049, -0.008], [-0.001, -0.049, 0.008]),   # across its x axis
    (6, 5, [-0.006, 0.018, 0.57], [-0.006, -0.018, -0.57]),     # the same end, other side
])
def test_a_primitive_never_tried_plans_with_the_mirror_image_of_its_partner(
        primitive, partner, partner_mean, mean):
    # The sim's eraser: p5 (-5.8 mm, 18.2 mm, 0.572 rad), p6 (-6.1 mm, -17.7 mm, -0.550 rad).
    store = ModelStore([eraser_model(partner, partner_mean)], {"eraser": "eraser"})
    model = store.model_for("eraser", "eraser", primitive)
    assert model.primitive == primitive and model.count == 3
    np.testing.assert_allclose(model.mean, mean)
    np.testing.assert_allclose(model.variance, store.get("eraser", partner).variance)
    assert ("eraser", primitive) not in store.models          # never written to the file


def test_only_a_partner_is_mirrored():
    with pytest.raises(ModelError, match="primitive 2 mirrors primitive 1, not 3"):
        mirrored(eraser_model(3, [0.0, 0.05, 0.0]), 2)


def test_own_trials_and_class_mates_come_before_a_mirror_image():
    store = ModelStore([eraser_model(1, [0.05, 0.0, 0.0]), eraser_model(2, [-0.03, 0.0, 0.0])],
                       {"eraser": "eraser"})
    assert store.model_for("eraser", "eraser", 2).mean[0] == -0.03
    store.add(eraser_model(4, [0.0, -0.04, 0.0]), "eraser")
    store.add(ForwardModel("eraser_2", 3, 0.05, 5, np.array([0.0, 0.045, 0.0]), np.zeros(3)),
              "eraser")
    assert store.model_for("eraser", "eraser", 3).object_id == "eraser_2"
    # A single trial of its own does not beat the mirror of two or more of the partner.
    store.add(eraser_model(6, [0.0, -0.01, -0.3], count=1), "eraser")
    store.add(eraser_model(5, [0.0, 0.02, 0.5], count=2), "eraser")
    assert store.model_for("eraser", "eraser", 6).mean[2] == -0.5


def test_an_assumed_model_is_the_last_resort_and_never_saved(tmp_path):
    spec = load_scenario("clean").object("remote")
    store = ModelStore([eraser_model(3, [0.0, 0.05, 0.0])], {"eraser": "eraser"})
    assumed = rule_model(spec, 1)
    np.testing.assert_allclose(assumed.variance, plausible_spread(assumed.mean) ** 2)
    store.assume(assumed)
    assert store.model_for("remote", "remote", 1) is assumed
    assert store.model_for("remote", "remote", 2) is None
    store.add(ForwardModel("remote", 1, 0.05, 1, np.array([0.0499, 0.0, 0.0]), np.zeros(3)),
              "remote")
    assert store.model_for("remote", "remote", 1).mean[0] == 0.0499   # its own first trial
    store.save(tmp_path / "models.yaml")
    assert ModelStore.load(tmp_path / "models.yaml").assumed == {}


def test_a_primitive_never_tried_borrows_a_class_mates_model(store):
    """plate_1 has no model of primitive 3 and plate_9 none at all: both plan with the plate
    that has the most trials of it; a single own trial does not yet replace that."""
    partial = ModelStore([m for (o, p), m in store.models.items() if (o, p) != ("plate_1", 3)],
                         store.classes)
    objects = [("plate_1", "plate", "cylinder"), ("plate_9", "plate", "cylinder")]
    with pytest.raises(ModelFileError, match="plate_9: no models"):
        partial.check_covers(objects, every_primitive=False)
    partial.check_covers(objects, borrow=True)
    best = partial.borrowed("plate", 3)
    assert best.count == max(m.count for (o, p), m in partial.models.items()
                             if p == 3 and partial.classes[o] == "plate")
    assert partial.model_for("plate_1", "plate", 3) is best
    assert partial.model_for("plate_9", "plate", 3) is best
    assert partial.model_for("mug_1", "mug", 3) is None       # no mug learned anything
    rates, available = partial.rate_table(["plate_1", "plate_9"], ["cylinder", "cylinder"],
                                          ["plate", "plate"])
    assert available[:, :4].all()
    np.testing.assert_allclose(rates[1, 2], best.mean / best.push_length)
    partial.add(ForwardModel("plate_9", 3, 0.05, 1, np.array([0.0, 0.03, 0.0]), np.zeros(3)),
                "plate")
    assert partial.model_for("plate_9", "plate", 3) is best
    with pytest.raises(ModelFileError, match="none of a 'mug'"):
        partial.check_covers([("mug_1", "mug", "cylinder")], borrow=True)
