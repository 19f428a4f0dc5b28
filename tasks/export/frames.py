"""An episode's control steps resampled to one row per video frame, as LeRobot's rows are.

``worldline simulate`` records a control step every 1 / control_hz s (50 Hz): the robot's joint
state at the step's start time and the action it then applies until the next step. Cameras
render frame ``i`` at ``i / fps`` (30 fps), at the first physics substep at or after that
instant (tasks/sim/episode.py). Row ``i`` of the export takes the step in force at the frame's
timestamp, sample-and-hold: the last step whose start time is at or before ``i / fps`` (to
within 1e-6 s, as both times are computed in floating point). Its state is the one recorded at
that step's start (at most one control period, 20 ms, before the frame) and its action the one
being applied while the frame is rendered. Nothing is interpolated, so every exported value is
one the simulator recorded; the steps between frames are left out (at 50 Hz and 30 fps, two
steps in five).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tasks.export.sources import Episode

# Frame times i / fps and step times k / control_hz are the same instant to within this.
SAME_INSTANT_S = 1e-6


@dataclass
class Rows:
    """One episode's rows: ``frames`` of them, float32 vectors and int64 indices."""

    timestamp: np.ndarray  # (F,) float32 s, i / fps
    frame_index: np.ndarray  # (F,) int64
    step: np.ndarray  # (F,) int64, the control step each row took
    state: np.ndarray  # F x 2J float32: joint positions, then joint velocities
    environment_state: np.ndarray  # F x 7N float32: each object's xyz + quaternion wxyz
    action: np.ndarray  # F x A float32

    def __len__(self) -> int:
        return len(self.frame_index)


def steps_at(step_times: np.ndarray, frame_times: np.ndarray) -> np.ndarray:
    """For each frame time, the index of the last step starting at or before it (the first
    step for a frame before any step)."""
    k = np.searchsorted(step_times, frame_times + SAME_INSTANT_S, side="right") - 1
    return np.clip(k, 0, len(step_times) - 1)


def resample(episode: Episode) -> Rows:
    frames = np.arange(episode.frames, dtype=np.int64)
    times = frames / float(episode.fps)
    k = steps_at(episode.time, times)
    state = np.concatenate([episode.joint_pos[k], episode.joint_vel[k]], axis=1)
    return Rows(timestamp=times.astype(np.float32), frame_index=frames, step=k.astype(np.int64),
                state=state.astype(np.float32), environment_state=episode.object_pose[k].astype(np.float32),
                action=episode.action[k].astype(np.float32))
