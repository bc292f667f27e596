"""An estimate that explains the detections worse than triangulating them does, told without the truth.

With three cameras or more, each camera c's detections u_c can be held out of a per-tick triangulation:
X₋c, the confidence-weighted DLT of the *other* cameras' detections, never saw u_c. The tracker's
estimate E saw every camera, u_c included. At each tick t, over the joints j that c sees and the others
triangulate,

    e^E_{c,j} = ‖π_c(E_j) − u_{c,j}‖,      e^X_{c,j} = ‖π_c(X₋c,j) − u_{c,j}‖        (pixels),

and the estimate's **held-out ratio** is

    q_t = median e^E / median e^X,

the medians pooled over every camera and joint in a window of ``WINDOW`` ticks centred on t (a swapped or
thrown detection moves neither). An estimate that follows the detections has q well below 1: it saw u_c,
the triangulation did not. One that the prior has pulled off them explains camera c worse than the other
cameras do without it: q above 1. A tick is *worse than triangulation* where q > ``WORSE_RATIO``.

No noise model enters: the detector's errors, whatever their correlation from frame to frame, and the
calibration's, are in both e^E and e^X alike. (A flag from the triangulation's frame-to-frame noise was tried
first: it separated on the bench and marked every tick of ukf-real on the Pose2Sim multi-person demo's real
detections, whose errors are correlated across frames: ``docs/results/2026-11-27-start-and-flag.md``.)

Measured (``docs/results/2026-11-27-held-out.md``): on the real-format bench (4 cameras, 8 walks of people the
priors never saw, 5 presets, seeds 0 and 1), every run at 1.3× per-frame DLT's 3D error or more was over
``WORSE_RATIO`` on ≥ 77 % of its ticks, one run of 31 below 0.85× on most of its ticks (3 % of those runs'
ticks on average); on real detections (the Pose2Sim multi-person demo, caliscope's 4 webcams) ukf-real and
pf-diffusion-local had q = 0.55–0.65 over the run.
"""

from __future__ import annotations

import numpy as np

from priortrack.geometry.camera import PinholeCamera, pixel_errors
from priortrack.geometry.triangulation import triangulate

#: Ticks pooled about each tick judged.
WINDOW = 31
#: A tick is worse than triangulation where its held-out ratio q is above this.
WORSE_RATIO = 1.2
#: Fewest (camera, joint) pixel errors a window needs to be judged.
MIN_ERRORS = 20
#: Cameras the ratio needs: one held out, two to triangulate without it.
MIN_CAMERAS = 3


def held_out_errors(cameras: list[PinholeCamera], E: np.ndarray, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(e^E, e^X), each (C, T, J) pixels (module docstring), NaN where camera c does not see joint j at the tick
    or the other cameras do not triangulate it.

    Args:
        cameras: the C ≥ ``MIN_CAMERAS`` cameras, in E's frame.
        E: (T, J, 3) the estimate's joints, in the detections' joint definitions.
        z: (T, C, J, 3) the detections: pixels and confidence (0 or NaN: unseen).
    """
    C = len(cameras)
    uv = z[..., :2].transpose(1, 0, 2, 3)                                       # (C, T, J, 2)
    confidence = np.nan_to_num(z[..., 2]).transpose(1, 0, 2)                    # (C, T, J)
    e_E, e_X = np.full(confidence.shape, np.nan), np.full(confidence.shape, np.nan)
    for c, camera in enumerate(cameras):
        others = [k for k in range(C) if k != c]
        X = triangulate([cameras[k] for k in others], uv[others], confidence[others])
        by_estimate, by_others = (pixel_errors(camera, points, uv[c], confidence[c]) for points in (E, X))
        judged = np.isfinite(by_estimate) & np.isfinite(by_others)
        e_E[c], e_X[c] = np.where(judged, by_estimate, np.nan), np.where(judged, by_others, np.nan)
    return e_E, e_X


def held_out_ratio(e_E: np.ndarray, e_X: np.ndarray) -> np.ndarray:
    """(T,) q_t (module docstring) from the errors (C, T, J) of :func:`held_out_errors`; NaN where the window
    about t holds fewer than ``MIN_ERRORS`` of them."""
    T = e_E.shape[1]
    half = WINDOW // 2
    q = np.full(T, np.nan)
    for t in range(T):
        window = slice(max(0, t - half), min(T, t + half + 1))
        a, b = e_E[:, window], e_X[:, window]
        if np.isfinite(a).sum() >= MIN_ERRORS:
            q[t] = np.nanmedian(a) / max(float(np.nanmedian(b)), 1e-9)
    return q
