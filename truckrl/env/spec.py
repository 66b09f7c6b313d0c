"""The specs of :class:`~truckrl.env.TruckEnv`: the reference for its keys, shapes and features.

Spec tree (``*B`` = batch dims, ``R`` = LiDAR beams; the intersection task's keys)::

    observation  float32 [*B, 26]  numeric features (table below; a task may append extras)
    lidar        float32 [*B, R]   first-hit range / max_range, in [0, 1]
    action       float32 [*B, 2]   [-1, 1]: (longitudinal, lateral) command, scaled to the
                                   control mode's per-truck limit (see truckrl.sim.control)
    reward       float32 [*B, 1]
    done / terminated / truncated  bool [*B, 1]
    info (also in the observation spec, logged by training):
      success, collision, jackknife, action_nonfinite   bool [*B, 1]
      r_progress, r_tractor_heading, r_trailer_heading,
      r_time, r_success, r_collision, r_timeout         float32 [*B, 1]  reward terms (sum = reward)
      pos_error [m], tractor_heading_error [rad],
      trailer_heading_error [rad]                       float32 [*B, 1]  current errors to the goal
      step_count int64 [*B, 1];  difficulty float32 [*B, 1]

Numeric observation (index -> meaning -> normalisation). ``theta`` tractor heading, ``phi``
articulation, ``psi_g`` goal heading; geometry and limits map their configured ``[min, max]``
range onto ``[-1, 1]``:

=====  ===================================================  ==============================
index  meaning                                              normalisation
=====  ===================================================  ==============================
0, 1   goal rear axle in the tractor frame (x fwd, y left)  / 50 m (paper)
2, 3   sin, cos of (psi_g - theta)                          none: in [-1, 1]
4, 5   sin, cos of (psi_g - theta - phi)  (trailer)         none: in [-1, 1]
6, 7   sin, cos of phi                                      none: in [-1, 1]
8..13  speed, accel, jerk, steer, steer rate, steer accel   / their per-truck limit
14     wheelbase L_t                                        range -> [-1, 1]
15     kingpin offset a_tk                                  range -> [-1, 1]
16     trailer wheelbase L_ka                               range -> [-1, 1]
17     tractor front overhang                               range -> [-1, 1]
18     tractor rear overhang                                range -> [-1, 1]
19     tractor width                                        range -> [-1, 1]
20     trailer rear overhang                                range -> [-1, 1]
21     trailer width                                        range -> [-1, 1]
22     max steering angle                                   range -> [-1, 1]
23     max speed                                            range -> [-1, 1]
24     limit of the longitudinal command (mode's)           range -> [-1, 1]
25     limit of the lateral command (mode's)                range -> [-1, 1]
=====  ===================================================  ==============================

The LiDAR sits at the centre of the tractor body; beam ``i`` points ``beam_angles(R, fov)[i]``
from the tractor heading. Reward, success and termination: :mod:`truckrl.tasks.intersection.task`.
Termination: success, collision or jack-knife -> ``terminated``; step limit -> ``truncated``.
Non-finite actions are replaced by 0 before they touch the state (no host sync needed to detect
them) and flagged in ``action_nonfinite``; ``nonfinite_action="error"`` raises instead (that check
syncs with the device every step, so it is a debugging option).
"""

from __future__ import annotations

import torch
from torchrl.data import Bounded, Categorical, Composite, TensorSpec, Unbounded

from truckrl.tasks import FLAG_KEYS, Task

#: Observation keys of the specs: the numeric features and the LiDAR ranges.
OBS_KEY = "observation"
LIDAR_KEY = "lidar"


def build_specs(
    task: Task, num_envs: int, num_beams: int, device: torch.device
) -> dict[str, TensorSpec]:
    """The specs of ``num_envs`` trucks of ``task`` (tree in the module docstring), by the
    ``EnvBase`` attribute they are assigned to: ``observation_spec``, ``action_spec``,
    ``reward_spec`` and ``done_spec``."""
    n, dev = num_envs, device
    col = (n, 1)
    info = {k: Categorical(2, col, dtype=torch.bool, device=dev) for k in FLAG_KEYS}
    for k in (*task.reward_keys, *task.error_keys, "difficulty"):
        info[k] = Unbounded(col, dtype=torch.float32, device=dev)
    info["step_count"] = Unbounded(col, dtype=torch.int64, device=dev)
    observation = {
        OBS_KEY: Unbounded((n, task.num_features), dtype=torch.float32, device=dev),
        LIDAR_KEY: Bounded(0.0, 1.0, (n, num_beams), dtype=torch.float32, device=dev),
    }
    done = Categorical(2, col, dtype=torch.bool, device=dev)
    return {
        "observation_spec": Composite(**observation, **info, shape=(n,), device=dev),
        "action_spec": Bounded(-1.0, 1.0, (n, 2), dtype=torch.float32, device=dev),
        "reward_spec": Unbounded(col, dtype=torch.float32, device=dev),
        "done_spec": Composite(
            done=done, terminated=done.clone(), truncated=done.clone(), shape=(n,), device=dev
        ),
    }
