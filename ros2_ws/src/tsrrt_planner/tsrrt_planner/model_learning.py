"""Learned forward models of push primitives (Sec. III-B, Fig. 2, Eq. 9).

A ForwardModel is the Gaussian P(delta_s | a, o) of one primitive a on one object o: the mean and
variance of the displacement (dx, dy, dtheta) in the object frame at the start of the push.

Choices (repeated in docs/planner.md):

* Eq. 9 is Welford's online update; we keep the mean and M2 = n sigma^2 (sum of squared
  deviations) instead of sigma itself, which is algebraically the same update without the square
  root and numerically stable. `variance` is Eq. 9's sigma^2 (divide by n);
  `sample_variance` divides by n - 1 and feeds the confidence interval.
* The paper's stopping rule sigma^2 < sigma_ref^2 = 0.4 gives no units. We read it per component
  in centimetres squared for x and y and degrees squared for theta (the units of the paper's
  Fig. 3), i.e. sigma < 6.3 mm and sigma < 0.63 deg. The sample variance converges to the push's
  true variance, not to zero, so this rule only ends when the true noise is already below the
  threshold; `PaperStoppingRule` therefore also caps the trials (max_trials) and needs
  min_trials >= 2, since one sample has variance 0.
* The better rule, `ConfidenceStoppingRule`, stops when the 95 % confidence half-width of the
  *mean* (Student t, t * s / sqrt(n)) is below a tolerance for every component: that is what
  planning with the mean needs, and it shrinks with more trials whatever the noise is. Bounded by
  min_trials and max_trials.
* Push length: models are learned at a nominal push length (the paper's 5 cm). For a push of
  another length the mean displacement is scaled linearly (`predict`): in quasi-static pushing
  the object moves with the pusher once in contact, so displacement is close to proportional to
  the pusher's travel over the short pushes used here. The planner limits lengths to
  [MIN_PUSH_LENGTH, MAX_PUSH_LENGTH] to stay in that regime.

The model file (`ModelStore.save`/`load`) is YAML text:

    format: tsrrt-forward-models
    version: 1
    units: {position: m, angle: rad}
    objects:
      <object id>:
        class: <object class>
        primitives:
          <primitive 1-6>: {push_length: 0.05, count: 12, mean: [dx, dy, dth], m2: [.., .., ..]}

`count` is the number of trials, `mean` the mean displacement and `m2` the sums of squared
deviations from it (so variance = m2 / count). It is written atomically (temporary file in the
same directory, fsync, os.replace); a file that cannot be parsed or does not match what is asked
for raises ModelFileError and is left untouched.
"""

from __future__ import annotations

import math
import os
import tempfile
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np
import yaml
from scipy import stats

from tsrrt_common.geometry import Pose2D
from tsrrt_executor.push_primitives import DEFAULT_PUSH_LENGTH, MAX_PUSH_LENGTH, primitives_for
from tsrrt_planner.errors import ModelError, ModelFileError

FILE_FORMAT = "tsrrt-forward-models"
FILE_VERSION = 1
MIN_PUSH_LENGTH = 0.002
CENTIMETRE = 0.01
DEGREE = math.pi / 180.0

# APPLY_ACTION(object_id, primitive, push_length) -> (delta_s (3,) in the object frame, new pose)
ApplyAction = Callable[[str, int, float], tuple[np.ndarray, Pose2D]]


@dataclass
class DisplacementStats:
    """Running mean and M2 of displacements (Eq. 9, Welford form)."""

    count: int = 0
    mean: np.ndarray = field(default_factory=lambda: np.zeros(3))
    m2: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def update(self, delta: np.ndarray) -> None:
        """UPDATEDISTR: fold one displacement (3,) into the distribution (Eq. 9)."""
        delta = np.asarray(delta, dtype=float).reshape(3)
        if not np.all(np.isfinite(delta)):
            raise ModelError(f"displacement must be finite, got {delta.tolist()}")
        self.count += 1
        previous_mean = self.mean
        self.mean = previous_mean + (delta - previous_mean) / self.count
        self.m2 = self.m2 + (delta - self.mean) * (delta - previous_mean)

    @property
    def variance(self) -> np.ndarray:
        """Eq. 9's sigma^2 (population variance), (3,); 0 before two samples."""
        return self.m2 / self.count if self.count else np.zeros(3)

    @property
    def sample_variance(self) -> np.ndarray:
        """Unbiased variance (3,), infinite before two samples."""
        return self.m2 / (self.count - 1) if self.count > 1 else np.full(3, np.inf)

    def mean_half_width(self, confidence: float = 0.95) -> np.ndarray:
        """Half-width (3,) of the two-sided confidence interval of the mean (Student t)."""
        if self.count < 2:
            return np.full(3, np.inf)
        t = stats.t.ppf(0.5 + confidence / 2.0, self.count - 1)
        return t * np.sqrt(self.sample_variance / self.count)


class StoppingRule(Protocol):
    """Decides when LEARN_MODEL has tried a primitive often enough."""

    min_trials: int

    def done(self, statistics: DisplacementStats) -> bool: ...


def _scaled(values: np.ndarray, position_unit: float, angle_unit: float, power: int) -> np.ndarray:
    return values / np.array([position_unit, position_unit, angle_unit]) ** power


@dataclass(frozen=True)
class PaperStoppingRule:
    """Fig. 2 line 3: stop once sigma^2 < sigma_ref^2 in every component (cm^2 and deg^2)."""

    sigma_ref_sq: float = 0.4
    position_unit: float = CENTIMETRE
    angle_unit: float = DEGREE
    min_trials: int = 2
    max_trials: int = 30

    def __post_init__(self) -> None:
        _check_trials(self.min_trials, self.max_trials, minimum=2)

    def done(self, statistics: DisplacementStats) -> bool:
        if statistics.count >= self.max_trials:
            return True
        variance = _scaled(statistics.variance, self.position_unit, self.angle_unit, 2)
        return statistics.count >= self.min_trials and bool(np.all(variance < self.sigma_ref_sq))


@dataclass(frozen=True)
class ConfidenceStoppingRule:
    """Stop once the confidence half-width of the mean is within tolerance in every component."""

    position_tolerance: float = 0.003
    angle_tolerance: float = 1.0 * DEGREE
    confidence: float = 0.95
    min_trials: int = 3
    max_trials: int = 20

    def __post_init__(self) -> None:
        _check_trials(self.min_trials, self.max_trials, minimum=2)
        if not (self.position_tolerance > 0 and self.angle_tolerance > 0
                and 0 < self.confidence < 1):
            raise ModelError("tolerances must be > 0 and confidence in (0, 1)")

    def done(self, statistics: DisplacementStats) -> bool:
        if statistics.count >= self.max_trials:
            return True
        tolerance = np.array([self.position_tolerance, self.position_tolerance,
                              self.angle_tolerance])
        return statistics.count >= self.min_trials and bool(
            np.all(statistics.mean_half_width(self.confidence) <= tolerance))


def _check_trials(min_trials: int, max_trials: int, minimum: int) -> None:
    if not minimum <= min_trials <= max_trials:
        raise ModelError(f"need {minimum} <= min_trials <= max_trials, got {min_trials}, "
                         f"{max_trials}")


@dataclass(frozen=True)
class ForwardModel:
    """P(delta_s | a, o) for one primitive on one object, learned at `push_length`."""

    object_id: str
    primitive: int
    push_length: float
    count: int
    mean: np.ndarray  # (3,) mean displacement (dx, dy, dtheta) in the object frame
    m2: np.ndarray    # (3,) sums of squared deviations from the mean

    @classmethod
    def from_stats(cls, object_id: str, primitive: int, push_length: float,
                   statistics: DisplacementStats) -> ForwardModel:
        return cls(object_id, primitive, push_length, statistics.count,
                   statistics.mean.copy(), statistics.m2.copy())

    @property
    def variance(self) -> np.ndarray:
        return self.m2 / self.count

    def predict(self, push_length: float) -> np.ndarray:
        """Mean displacement (3,) for a push of `push_length`, scaled linearly from the nominal."""
        if not MIN_PUSH_LENGTH <= push_length <= MAX_PUSH_LENGTH:
            raise ModelError(f"push length {push_length} m outside [{MIN_PUSH_LENGTH}, "
                             f"{MAX_PUSH_LENGTH}] m")
        return self.mean * (push_length / self.push_length)


def LEARN_MODEL(object_id: str, primitives: Sequence[int], s_init: Pose2D,
                apply_action: ApplyAction, rule: StoppingRule | None = None,
                push_length: float = DEFAULT_PUSH_LENGTH) -> tuple[dict[int, ForwardModel],
                                                                   Pose2D]:
    """Fig. 2: try every primitive on the object until the stopping rule is satisfied.

    Args:
        object_id: the object o.
        primitives: the actions A.
        s_init: pose of the object before learning.
        apply_action: APPLY_ACTION, executes one push and observes (delta_s, new pose); the
            closed loop passes one that acts through ROS, tests a simulated pusher.
        rule: stopping rule, default ConfidenceStoppingRule().
        push_length: nominal push length, metres.

    Returns:
        The model of each primitive and the object's pose after the last push.
    """
    rule = rule or ConfidenceStoppingRule()
    if not primitives:
        raise ModelError(f"LEARN_MODEL({object_id!r}): no primitives given")
    s = s_init
    models: dict[int, ForwardModel] = {}
    for a in primitives:
        statistics = DisplacementStats()
        while not rule.done(statistics):
            delta_s, s = apply_action(object_id, a, push_length)
            statistics.update(delta_s)
        models[a] = ForwardModel.from_stats(object_id, a, push_length, statistics)
    return models, s


# Primitive -> (its mirror-image partner, the object axis it is mirrored across: 0 = x, 1 = y).
# Fig. 5: 1 and 2 push the two ends towards each other (mirrored across the object's y axis),
# 3 and 4 the two long faces, 5 and 6 the same end from either side (across its x axis).
MIRROR_PARTNER = {1: (2, 1), 2: (1, 1), 3: (4, 0), 4: (3, 0), 5: (6, 0), 6: (5, 0)}


def mirror_flip(primitive: int) -> np.ndarray:
    """Signs (3,) that reflect a displacement of the partner of `primitive` into one of it.

    A push mirrored across an axis of a symmetric object moves it the mirrored way: across the
    y axis (dx, dy, dtheta) becomes (-dx, dy, -dtheta), across the x axis (dx, -dy, -dtheta).
    """
    return np.array([-1.0, 1.0, -1.0]) if MIRROR_PARTNER[primitive][1] == 1 else np.array(
        [1.0, -1.0, -1.0])


def mirrored(model: ForwardModel, primitive: int) -> ForwardModel:
    """`model` of the partner of `primitive` reflected into a model of `primitive` (mirror_flip).
    The spread is the same; the count stays the partner's trials (none are this primitive's).
    """
    partner = MIRROR_PARTNER[primitive][0]
    if model.primitive != partner:
        raise ModelError(f"primitive {primitive} mirrors primitive {partner}, not "
                         f"{model.primitive}")
    return ForwardModel(model.object_id, primitive, model.push_length, model.count,
                        model.mean * mirror_flip(primitive), model.m2.copy())


@dataclass(frozen=True)
class MirrorCheck:
    """Learn a primitive from its mirror partner's trials and one of its own that confirms them.

    The objects are symmetric and of uniform density, so trying both primitives of a mirror pair
    (MIRROR_PARTNER) until each rule holds learns the same displacement twice: 30 s of a clean
    demo's 110 s were learning. A primitive counts as learned once its partner's stopping rule
    holds and the mean of its own trials (a single one will do) lies within these tolerances of
    the partner's mirrored mean. It is planned with the mirrored model (ModelStore.model_for)
    until its own executed pushes take over; a trial that disagrees (the arm or the contact is
    not symmetric after all) leaves it to be learned in full.
    """

    position_tolerance: float = 0.004
    angle_tolerance: float = 2.0 * DEGREE

    def __post_init__(self) -> None:
        if not (self.position_tolerance > 0 and self.angle_tolerance > 0):
            raise ModelError("mirror check tolerances must be > 0")

    def confirmed(self, primitive: int, statistics: Mapping[int, DisplacementStats],
                  rule: StoppingRule) -> bool:
        """Whether `primitive`'s own trials confirm its partner's mirrored mean."""
        own = statistics.get(primitive)
        source = statistics.get(MIRROR_PARTNER[primitive][0])
        if own is None or own.count == 0 or source is None or source.count < 2 or not rule.done(
                source):
            return False
        error = np.abs(own.mean - source.mean * mirror_flip(primitive))
        return bool(np.all(error <= [self.position_tolerance, self.position_tolerance,
                                     self.angle_tolerance]))


def learned(primitive: int, statistics: Mapping[int, DisplacementStats], rule: StoppingRule,
            mirror: MirrorCheck | None = None) -> bool:
    """Whether `primitive` needs no more trials: its own rule holds, or `mirror` confirms it."""
    own = statistics.get(primitive)
    if own is not None and rule.done(own):
        return True
    return mirror is not None and mirror.confirmed(primitive, statistics, rule)


class ModelStore:
    """Forward models of every (object, primitive), with the object classes they were learned for.
    """

    def __init__(self, models: Iterable[ForwardModel] = (),
                 classes: dict[str, str] | None = None) -> None:
        self.models: dict[tuple[str, int], ForwardModel] = {}
        self.classes: dict[str, str] = dict(classes or {})
        # Models assumed without any trial (assume); planned with last, never saved.
        self.assumed: dict[tuple[str, int], ForwardModel] = {}
        # Longest push (m) per object whose longer push turned it off its prediction (cap_push).
        self.push_caps: dict[str, float] = {}
        for model in models:
            self.add(model)

    def add(self, model: ForwardModel, object_class: str | None = None) -> None:
        self.models[(model.object_id, model.primitive)] = model
        if object_class is not None:
            self.classes[model.object_id] = object_class

    def assume(self, model: ForwardModel) -> None:
        """Plan with `model` where nothing learned covers its primitive (model_for's last
        resort); it is not a trial, so it is neither saved nor averaged into what is learned."""
        self.assumed[(model.object_id, model.primitive)] = model

    def cap_push(self, object_id: str, length: float) -> bool:
        """Plan the object's pushes no longer than `length` from now on: a longer one turned it
        where the linear model did not say, so its models hold only up to what was learned.
        Kept in the model file. Returns whether this lowered the object's cap."""
        if length >= self.push_caps.get(object_id, math.inf):
            return False
        self.push_caps[object_id] = float(length)
        return True

    def get(self, object_id: str, primitive: int) -> ForwardModel:
        try:
            return self.models[(object_id, primitive)]
        except KeyError:
            raise ModelError(f"no forward model for object {object_id!r}, primitive "
                             f"{primitive}; known objects: {sorted(self.classes)}") from None

    def borrowed(self, object_class: str, primitive: int) -> ForwardModel | None:
        """The model of `primitive` with the most trials among the objects of `object_class`."""
        candidates = [m for (o, p), m in self.models.items()
                      if p == primitive and self.classes.get(o) == object_class]
        return max(candidates, key=lambda m: m.count, default=None)

    def model_for(self, object_id: str, object_class: str, primitive: int
                  ) -> ForwardModel | None:
        """The model to plan with, the first of:

        1. the object's own, once it has two trials;
        2. that of the class-mate with the most trials (objects of a class differ little in
           mass and friction);
        3. the mirror image of the primitive's partner (MIRROR_PARTNER), the object's own or a
           class-mate's, with two trials (the objects are symmetric, of uniform density);
        4. the object's own single trial;
        5. a model assumed for it (assume); else None.

        2, 3 and 5 are for primitives the robot could not try on this object, blocked while
        learning: they are still worth planning with.
        """
        own = self.models.get((object_id, primitive))
        if own is not None and own.count >= 2:
            return own
        same_class = self.classes.get(object_id, object_class) == object_class
        mate = self.borrowed(object_class, primitive) if same_class else None
        if mate is not None and mate.count >= 2:
            return mate
        partner = MIRROR_PARTNER.get(primitive)
        if partner is not None:
            sources = [self.models.get((object_id, partner[0])),
                       self.borrowed(object_class, partner[0]) if same_class else None]
            for source in sources:
                if source is not None and source.count >= 2:
                    return mirrored(source, primitive)
        return own or self.assumed.get((object_id, primitive))

    def check_covers(self, objects: Sequence[tuple[str, str, str]],
                     every_primitive: bool = True, borrow: bool = False) -> None:
        """Raise ModelFileError unless every (id, class, shape) has models learned for the same
        class: of each primitive of its shape, or with every_primitive=False of at least one
        (a primitive the robot could not try, e.g. blocked while learning, is then simply not
        available to the planner). With borrow=True a class-mate's model counts (model_for)."""
        problems = []
        for object_id, object_class, shape in objects:
            stored_class = self.classes.get(object_id)
            if stored_class is not None and stored_class != object_class:
                problems.append(f"{object_id}: models are for class {stored_class!r}, the "
                                f"object is a {object_class!r}")
                continue
            if borrow:
                missing = [p for p in primitives_for(shape)
                           if self.model_for(object_id, object_class, p) is None]
            elif stored_class is None:
                problems.append(f"{object_id}: no models")
                continue
            else:
                missing = [p for p in primitives_for(shape) if (object_id, p) not in self.models]
            if borrow and len(missing) == len(primitives_for(shape)):
                problems.append(f"{object_id}: no models, and none of a {object_class!r}")
                continue
            if missing and (every_primitive or len(missing) == len(primitives_for(shape))):
                problems.append(f"{object_id}: no model for primitives {missing}")
        if problems:
            raise ModelFileError("forward models do not match the objects: " + "; ".join(problems))

    def rate_table(self, object_ids: Sequence[str], shapes: Sequence[str],
                   classes: Sequence[str] | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Displacement per metre of push (n, 6, 3) and availability (n, 6) for the planner.

        Primitive p is column p - 1; primitives a shape does not have, or that have no model,
        are unavailable. Given the objects' classes, models are chosen by model_for.
        """
        rates = np.zeros((len(object_ids), 6, 3))
        available = np.zeros((len(object_ids), 6), bool)
        for i, (object_id, shape) in enumerate(zip(object_ids, shapes, strict=True)):
            for p in primitives_for(shape):
                model = (self.models.get((object_id, p)) if classes is None
                         else self.model_for(object_id, classes[i], p))
                if model is None:
                    continue
                rates[i, p - 1] = model.mean / model.push_length
                available[i, p - 1] = True
        return rates, available

    # ------------------------------------------------------------------ file format
    def to_document(self) -> dict[str, Any]:
        objects: dict[str, Any] = {}
        for (object_id, primitive), model in sorted(self.models.items()):
            entry = objects.setdefault(object_id, {"class": self.classes.get(object_id, ""),
                                                   "primitives": {}})
            entry["primitives"][primitive] = {
                "push_length": float(model.push_length), "count": int(model.count),
                "mean": [float(v) for v in model.mean], "m2": [float(v) for v in model.m2]}
        for object_id, cap in sorted(self.push_caps.items()):
            if object_id in objects:
                objects[object_id]["longest_push"] = cap
        return {"format": FILE_FORMAT, "version": FILE_VERSION,
                "units": {"position": "m", "angle": "rad"}, "objects": objects}

    def save(self, path: str | Path) -> None:
        """Write the models atomically: a crash leaves the old file or the new, never half."""
        path = Path(path)
        text = yaml.safe_dump(self.to_document(), sort_keys=False, default_flow_style=None)
        descriptor, temporary = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp",
                                                 dir=path.parent)
        try:
            with os.fdopen(descriptor, "w") as stream:
                stream.write(text)
                stream.flush()
                os.fsync(stream.fileno())
            os.replace(temporary, path)
        except BaseException:
            Path(temporary).unlink(missing_ok=True)
            raise

    @classmethod
    def load(cls, path: str | Path) -> ModelStore:
        """Read a model file; anything malformed raises ModelFileError naming file and field."""
        path = Path(path)
        try:
            text = path.read_text(encoding="utf-8")
        except OSError as error:
            raise ModelFileError(f"{path}: cannot read ({error.strerror})") from None
        except UnicodeDecodeError as error:
            raise ModelFileError(f"{path}: not UTF-8 text ({error.reason} at byte "
                                 f"{error.start})") from None
        try:
            document = yaml.safe_load(text)
        except yaml.YAMLError as error:
            raise ModelFileError(f"{path}: not valid YAML ({error})") from None
        return cls.from_document(document, str(path))

    @classmethod
    def from_document(cls, document: Any, source: str) -> ModelStore:
        def fail(where: str, problem: str) -> ModelFileError:
            return ModelFileError(f"{source}: {where}: {problem}")

        if not isinstance(document, dict):
            raise fail("(top level)", "expected a mapping")
        if document.get("format") != FILE_FORMAT:
            raise fail("format", f"expected {FILE_FORMAT!r}, got {document.get('format')!r}")
        if document.get("version") != FILE_VERSION:
            raise fail("version", f"unsupported version {document.get('version')!r}; this "
                       f"tsrrt reads {FILE_VERSION}")
        if document.get("units") != {"position": "m", "angle": "rad"}:
            raise fail("units", "expected {position: m, angle: rad}")
        objects = document.get("objects")
        if not isinstance(objects, dict) or not objects:
            raise fail("objects", "expected a non-empty mapping of object ids")
        store = cls()
        for object_id, entry in objects.items():
            where = f"objects.{object_id}"
            if not isinstance(entry, dict) or not (
                    {"class", "primitives"} <= set(entry) <= {"class", "primitives",
                                                              "longest_push"}):
                raise fail(where, "expected the fields 'class' and 'primitives', and "
                           "optionally 'longest_push'")
            if not isinstance(entry["class"], str) or not entry["class"]:
                raise fail(f"{where}.class", "expected a class name")
            primitives = entry["primitives"]
            if not isinstance(primitives, dict) or not primitives:
                raise fail(f"{where}.primitives", "expected a non-empty mapping")
            for primitive, raw in primitives.items():
                model = _parse_model(str(object_id), primitive, raw,
                                     f"{where}.primitives.{primitive}", fail)
                store.add(model, entry["class"])
            if "longest_push" in entry:
                store.cap_push(str(object_id), _push_length(entry["longest_push"],
                                                            f"{where}.longest_push", fail))
        return store


def _parse_model(object_id: str, primitive: Any, raw: Any, where: str,
                 fail: Callable[[str, str], ModelFileError]) -> ForwardModel:
    if isinstance(primitive, bool) or not isinstance(primitive, int) or not 1 <= primitive <= 6:
        raise fail(where, f"primitive must be an integer 1-6, got {primitive!r}")
    if not isinstance(raw, dict) or set(raw) != {"push_length", "count", "mean", "m2"}:
        raise fail(where, "expected exactly push_length, count, mean, m2")
    count = raw["count"]
    if isinstance(count, bool) or not isinstance(count, int) or count < 1:
        raise fail(f"{where}.count", f"expected an integer >= 1, got {count!r}")
    vectors = []
    for key in ("mean", "m2"):
        value = raw[key]
        if not (isinstance(value, list) and len(value) == 3 and all(
                isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                for v in value)):
            raise fail(f"{where}.{key}", f"expected 3 finite numbers, got {value!r}")
        vectors.append(np.array(value, dtype=float))
    if np.any(vectors[1] < 0):
        raise fail(f"{where}.m2", "sums of squared deviations cannot be negative")
    length = _push_length(raw["push_length"], f"{where}.push_length", fail)
    return ForwardModel(object_id, primitive, length, count, vectors[0], vectors[1])


def _push_length(value: Any, where: str, fail: Callable[[str, str], ModelFileError]) -> float:
    """A push length of a model file, in [MIN_PUSH_LENGTH, MAX_PUSH_LENGTH] metres."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not (
            MIN_PUSH_LENGTH <= value <= MAX_PUSH_LENGTH):
        raise fail(where, f"expected a length in [{MIN_PUSH_LENGTH}, {MAX_PUSH_LENGTH}] m, "
                   f"got {value!r}")
    return float(value)

