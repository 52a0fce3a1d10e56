import itertools
import math

import numpy as np

from lastmile.core.object_class import ObjectClass
from lastmile.sim.agents import WalkingAgent


class _World:
    """The little of the world a walker looks at: the clock, the shuttle far away, an RNG."""

    def __init__(self, seed: int = 0) -> None:
        self.t_s = 0.0
        self.agent_rng = np.random.default_rng(seed)

    def distance_to_ego_m(self, x_m: float, y_m: float) -> float:
        return 100.0

    def time_gap_s(self, x_m: float, y_m: float) -> float:
        return math.inf


def _crossing_walker(mean_gap_s: float, approach_m: float) -> WalkingAgent:
    return WalkingAgent(
        id=1,
        cls=ObjectClass.PEDESTRIAN,
        x_m=0.0,
        y_m=0.0,
        yaw_rad=math.pi / 2,
        speed_mps=0.0,
        length_m=0.5,
        width_m=0.5,
        rcs_dbsm=-8.0,
        start_xy=(0.0, 0.0),
        end_xy=(0.0, 8.0),
        walk_speed_mps=1.0,
        gap_s=3.0,
        respawn=True,
        mean_gap_s=mean_gap_s,
        approach_m=approach_m,
    )


def _run(walker: WalkingAgent, world: _World, seconds: float, dt_s: float = 0.1) -> list[tuple]:
    trace = []
    for _ in range(round(seconds / dt_s)):
        world.t_s += dt_s
        walker.step(world, dt_s)  # type: ignore[arg-type]
        trace.append((round(world.t_s, 3), walker.active, walker.x_m, walker.y_m, walker.walking))
    return trace


def test_respawn_gaps_follow_the_groups_mean_gap():
    # Each crossing takes 8 s; the idle gaps between pedestrians are exponential with mean_gap_s.
    world = _World(seed=1)
    walker = _crossing_walker(mean_gap_s=20.0, approach_m=0.0)
    trace = _run(walker, world, 4000.0)
    crossings = sum(1 for a, b in itertools.pairwise(trace) if not a[1] and b[1])
    # About 4000 / (8 + 20) = 143 crossings; with the old fixed 30 s gap it would be about 105.
    assert 120 <= crossings <= 165


def test_a_respawned_pedestrian_walks_up_to_the_kerb_in_view_before_crossing():
    world = _World(seed=2)
    walker = _crossing_walker(mean_gap_s=5.0, approach_m=4.0)
    trace = _run(walker, world, 60.0)
    reappear = next(i for i, (a, b) in enumerate(itertools.pairwise(trace)) if not a[1] and b[1])
    # It comes back on the far side (the next crossing goes the other way), 4 m behind that kerb...
    _, active, x, y, walking = trace[reappear + 1]
    assert active and not walking
    assert x == 0.0 and 8.0 + 3.0 <= y <= 8.0 + 4.0
    # ...and reaches the kerb (y = 8) walking, before it starts across.
    at_kerb = next(i for i in range(reappear + 1, len(trace)) if trace[i][3] == 8.0)
    assert 35 <= at_kerb - reappear <= 45  # 4 m at 1 m/s: about 40 steps of 0.1 s
    assert all(not w for *_, w in trace[reappear + 1 : at_kerb])
