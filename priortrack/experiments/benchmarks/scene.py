"""``priortrack bench scene``: the whole ``track --detections … --people all`` command on several people,
timed beside the single-person command on one of them (``bench real-track``'s run, same cameras and frames).

The input: CMU 49_18 (a person balancing in place: every camera sees everyone throughout) for each person,
each starting at another moment of the clip (played forward and back,
:func:`~priortrack.experiments.benchmarks.long.ping_pong`), on a grid 1.2 m apart, seen by ``cameras``
distorted cameras on a ring around them (:func:`~priortrack.experiments.benchmarks.ukf.ring_cameras`, a
Y-up world), with the scene bench's detector errors, occlusions and static false positive
(:func:`~priortrack.experiments.scenes.scene_keypoints`), written as a multi-person detector writes
them. Timed in this process as the command runs it: reading the files, the scene tracker, each person's
start and filter (the people side by side in one worker process per core, started as the command starts:
:func:`~priortrack.tracking.people.track_scene`'s ``workers``), writing an .npz.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

from priortrack.errors import PriortrackError
from priortrack.experiments.benchmarks.long import LOOP_SECONDS, ping_pong
from priortrack.experiments.benchmarks.real_track import MOTION, _ring_calibration, bench_real_track
from priortrack.experiments.benchmarks.timing import load_average
from priortrack.experiments.real_format import placed_walk
from priortrack.geometry.camera import PinholeCamera

#: People on the grid, metres apart.
SPACING = 1.2


def bench_scene(people: int = 4, cameras: int = 5, frames: int = 300, fps: float = 30.0, preset: str = "ukf-real",
                seed: int = 0, association: str = "joints") -> dict:
    """Seconds of the scene command on ``people`` × ``cameras`` × ``frames`` (who is who decided as
    ``association`` says: :class:`~priortrack.tracking.scene.SceneConfig`) and of the single-person command on one
    person with the same cameras and frames (module docstring)."""
    from priortrack.data.scene_detections import read_scene_detections
    from priortrack.experiments.scenes import scene_keypoints, write_scene_openpose
    from priortrack.tracking.people import track_scene
    from priortrack.tracking.person import TrackConfig
    from priortrack.tracking.scene import SceneConfig

    scene_config = SceneConfig(association=association)
    if not 1 <= people <= 9:
        raise PriortrackError(f"bench scene: people must be in [1, 9], got {people}")
    if not 3 <= cameras <= 12:
        raise PriortrackError(f"bench scene: cameras must be in [3, 12], got {cameras}")
    if not 10 <= frames <= 1800:
        raise PriortrackError(f"bench scene: frames must be in [10, 1800], got {frames}")
    clip = placed_walk(MOTION, "y", fps=fps, seconds=LOOP_SECONDS)
    side = int(np.ceil(np.sqrt(people)))
    X = np.stack([ping_pong(clip, frames + 37 * p)[37 * p:] +
                  SPACING * np.array([p % side - (side - 1) / 2, 0.0, p // side - (side - 1) / 2]) for p in range(people)])
    calibration = _ring_calibration(X.reshape(-1, 15, 3), cameras)
    views = [PinholeCamera.from_calibration(c) for c in calibration.cameras]
    rng = np.random.default_rng(seed)
    with tempfile.TemporaryDirectory() as tmp:
        folder = write_scene_openpose(scene_keypoints(X, views, rng, up="y"), Path(tmp) / "scene", rng)
        start = time.perf_counter()
        result = track_scene(read_scene_detections(folder, keypoints="body25b"), calibration, preset,
                             TrackConfig(fps=fps, seed=seed), scene_config)
        result.save(Path(tmp) / "scene.npz")
        seconds = time.perf_counter() - start
    single = bench_real_track(frames=frames, preset=preset, seed=seed, cameras=cameras, fps=fps)
    return {"people": people, "cameras": cameras, "frames": frames, "fps": fps, "preset": preset,
            "association": association,
            "people_tracked": len(result.person_ids), "command_seconds": seconds,
            "single_person_seconds": single["command_seconds"],
            "ratio_to_people_times_single": seconds / (people * single["command_seconds"]),
            "load_average": load_average()}
