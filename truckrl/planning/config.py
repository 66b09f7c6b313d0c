"""The planner's settings: :class:`PlannerConfig` (budget, parameterisation, search)."""

from __future__ import annotations

from dataclasses import dataclass

from truckrl.config.fields import param, validate

#: Planned scalars after the knots: pursuit switch distance, look-ahead, gain, trailer-law
#: weight, arrival speed (always sampled; unused ones do not matter).
NUM_EXTRA = 5


@dataclass
class PlannerConfig:
    """Budget and shape of the CEM planner (:mod:`truckrl.planning.rollout` describes the
    parameters a candidate plans, :mod:`truckrl.planning.search` the search)."""

    search: str = param(
        "knots",
        choices=("knots", "gears"),
        doc="knots: smooth steering and speed set-points (module rollout); gears: a sequence "
        "of forward / reverse legs along the task expert's paths (module gears; tasks that "
        "reverse)",
    )
    gears_init_std: float = param(
        0.25,
        lo=0.0,
        lo_open=True,
        hi=10.0,
        unit="-",
        doc="search=gears: initial std around the expert's prior (the parameters span [-1, 1])",
    )
    samples: int = param(256, lo=2, hi=1_000_000, unit="candidates", doc="per scene per iteration")
    iterations: int = param(12, lo=1, hi=100_000, unit="-", doc="CEM iterations per attempt")
    attempts: int = param(
        3, lo=1, hi=1000, unit="-", doc="independent CEM attempts per scene until one succeeds"
    )
    elite_frac: float = param(
        0.1, lo=0.0, lo_open=True, hi=1.0, unit="-", doc="fraction of the population kept as elites"
    )
    steer_knots: int = param(8, lo=1, hi=1000, unit="-", doc="steering set-points over the horizon")
    speed_knots: int = param(4, lo=1, hi=1000, unit="-", doc="speed set-points over the horizon")
    steer_axis: str = param(
        "distance",
        choices=("distance", "time"),
        doc="steering set-points spread over the distance driven (up to path_stretch x the "
        "start-goal distance) or over the horizon's steps",
    )
    speed_axis: str = param(
        "time", choices=("distance", "time"), doc="speed set-points: as steer_axis"
    )
    path_stretch: float = param(
        1.6, lo=0.1, hi=100.0, unit="-", doc="steer_axis=distance: knots span this x goal distance"
    )
    path_extra: float = param(
        10.0, lo=0.0, hi=1e4, unit="m", doc="steer_axis=distance: plus this many metres"
    )
    pursuit: str = param(
        "blend",
        choices=("blend", "none"),
        doc="blend: after a planned switch distance, steer by a planned blend of pure pursuit of "
        "the goal line by the tractor rear axle and by the trailer axle (articulation cascade); "
        "none: the knots steer alone",
    )
    lookahead: tuple[float, float] = param(
        (3.0, 30.0), lo=0.1, hi=1e4, unit="m", doc="pursuit: range of the planned look-ahead"
    )
    gain: tuple[float, float] = param(
        (0.05, 1.0),
        lo=0.0,
        lo_open=True,
        hi=100.0,
        unit="1/m",
        doc="pursuit: range of the planned articulation gain of the trailer law (per metre driven)",
    )
    arrival: bool = param(
        True,
        doc="cap the speed set-point by a braking profile (brake x max_accel) down to a planned "
        "arrival speed at the goal",
    )
    arrival_speed: tuple[float, float] = param(
        (0.05, 1.0), lo=0.0, hi=1.0, unit="-", doc="arrival: range of the planned speed / max_speed"
    )
    arrival_slack: float = param(
        0.5,
        lo=0.0,
        hi=100.0,
        unit="m",
        doc="arrival, a task that reverses: offset across the goal line the braking distance "
        "ignores",
    )
    brake: float = param(
        0.5, lo=0.0, lo_open=True, hi=1.0, unit="-", doc="arrival: deceleration / max_accel"
    )
    steer_prior: str = param(
        "none",
        choices=("none", "arc", "alternate"),
        doc="arc: the steering knots are residuals on the steering of a circular arc tangent to "
        "the start and goal heading lines, of planned radius (module doc; forward tasks only); "
        "alternate: a scene's attempts alternate between the arc (first) and the knots alone",
    )
    arc_init_std: float = param(
        0.3,
        lo=0.0,
        lo_open=True,
        hi=10.0,
        unit="-",
        doc="initial std of an attempt with the arc prior (the knots are corrections to it)",
    )
    speed_mean: float = param(
        0.0,
        lo=-1.0,
        hi=1.0,
        unit="-",
        doc="initial mean of the speed knots (-1 min, +1 max speed; a task that reverses: "
        "-1 -max_reverse_speed, 0 standstill)",
    )
    init_std: float = param(0.6, lo=0.0, lo_open=True, hi=10.0, unit="-", doc="initial knot std")
    min_std: float = param(0.002, lo=0.0, hi=10.0, unit="-", doc="floor of the knot std")
    smoothing: float = param(
        0.2, lo=0.0, hi=1.0, hi_open=True, unit="-", doc="weight of the old mean/std in an update"
    )
    mean_weight: float = param(
        0.5, lo=0.0, hi=100.0, unit="-", doc="weight of the mean error ratio in the score"
    )
    stop_margin: float = param(
        0.99,
        lo=0.0,
        hi=1.0,
        unit="-",
        doc="stop a scene once a success has every error / tolerance <= this (replay margin)",
    )
    scenes_per_batch: int = param(
        16, lo=1, hi=100_000, unit="scenes", doc="scenes rolled out together"
    )
    replay_candidates: int = param(
        3, lo=1, hi=100, unit="-", doc="successful sequences per scene kept for the replay"
    )
    compile: bool = param(True, doc="torch.compile the rollout step (compiled once per process)")
    seed: int = param(0, lo=0, hi=2**62, unit="-", doc="seed of the candidate sampling")

    def __post_init__(self) -> None:
        validate(self, "planner")

    @property
    def num_params(self) -> int:
        return self.steer_knots + self.speed_knots + NUM_EXTRA + (self.steer_prior != "none")
