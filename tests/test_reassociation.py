"""Who is who, decided through each person's own filter (priortrack.tracking.reassociation): the filters
stepped in halves (advance, predicted_measurement, correct) against their whole step and an independent
computation of the prediction, and the lockstep association on Pose2Sim's multi-person demo, where it undoes
an identity swap injected into the scene tracker's decisions."""

import numpy as np
import pytest
import torch

from priortrack import PriortrackError
from priortrack.data.calibration import read_calibration
from priortrack.data.scene_detections import read_scene_detections
from priortrack.filters.snapshot import KNOWN_FRAMES
from priortrack.geometry.camera import PinholeCamera
from priortrack.tracking.people import track_scene
from priortrack.tracking.person import TrackConfig, prepared, schedule
from priortrack.tracking.presets import load_preset
from priortrack.tracking.reassociation import predicts, reassociated
from priortrack.tracking.scene import SceneConfig, SceneTracker

from test_scene import POSE, QCA


@pytest.fixture(scope="module")
def demo():
    return read_scene_detections(POSE, keypoints="body25b"), read_calibration(QCA)


def _association(scene, calibration):
    cameras = [PinholeCamera.from_calibration(c) for c in calibration.cameras]
    uv, confidence = scene.eval15(0.3)
    return SceneTracker(cameras, 60.0).run(uv, confidence, scene.frames)


@pytest.mark.parametrize("preset", ["ukf-real", "pf-diffusion-local"])
def test_advance_then_correct_is_the_step_bit_for_bit(demo, preset):
    """Two runs prepared alike: one stepped whole, one in halves with its prediction read between; the same
    estimates and weights to the last bit."""
    scene, calibration = demo
    association = _association(scene, calibration)
    detections = association.detections_of(scene, 1)
    whole, halves = (prepared(detections, calibration, preset, TrackConfig(fps=60, seed=3)) for _ in range(2))
    runs = [person.filt.started(person.known, len(person.z), **person.initial) for person in (whole, halves)]
    for t in range(KNOWN_FRAMES, 30):
        a = whole.filt.step(whole.z[t])
        halves.filt.advance()
        mean, covariance = halves.filt.predicted_measurement()
        assert mean.shape == (4, 15, 2) and covariance.shape == (4, 15, 2, 2)
        b = halves.filt.correct(halves.z[t])
        np.testing.assert_array_equal(a.estimate, b.estimate)
        np.testing.assert_array_equal(np.asarray(a.weights), np.asarray(b.weights))
        for run, snap in zip(runs, (a, b)):
            run.record(snap)
    np.testing.assert_array_equal(runs[0].result().estimates, runs[1].result().estimates)


def test_the_unscented_prediction_is_filterpys_innovation_covariance_less_R(demo):
    """ukf-real: every point's predicted pixels' covariance P_zz (2 × 2) equals the diagonal block of filterpy's
    own innovation covariance S = P_zz + R (its unscented transform of the same sigma points) less R = σ² I,
    with every point detected at confidence 1, at the predicted pixels (none gated)."""
    scene, calibration = demo
    person = prepared(_association(scene, calibration).detections_of(scene, 0), calibration, "ukf-real",
                      TrackConfig(fps=60))
    person.filt.started(person.known, len(person.z))
    for t in range(KNOWN_FRAMES, 12):
        person.filt.step(person.z[t])
    person.filt.advance()
    mean, covariance = person.filt.predicted_measurement()
    z = np.concatenate([mean, np.ones(mean.shape[:-1] + (1,))], axis=-1)
    person.filt.correct(z)
    S = person.filt.kf.S
    assert S.shape == (4 * 15 * 2,) * 2
    blocks = np.stack([S[2 * k:2 * k + 2, 2 * k:2 * k + 2] for k in range(60)])
    sigma = person.model.likelihood.sigma_px
    np.testing.assert_allclose(blocks - sigma ** 2 * np.eye(2), covariance.reshape(60, 2, 2), rtol=1e-9, atol=1e-9)
    assert np.all(np.linalg.eigvalsh(covariance.reshape(60, 2, 2)) > 0)


def test_the_particle_prediction_is_the_clouds_weighted_moments_through_each_camera(demo):
    """pf-diffusion-local: the predicted pixels and their covariance are the weighted mean and covariance of
    every predicted particle's joints projected by each camera's own model (PinholeCamera.project, the lens
    included), computed here apart in float64."""
    scene, calibration = demo
    person = prepared(_association(scene, calibration).detections_of(scene, 0), calibration, "pf-diffusion-local",
                      TrackConfig(fps=60))
    person.filt.started(person.known, len(person.z), **person.initial)
    for t in range(KNOWN_FRAMES, 8):
        person.filt.step(person.z[t])
    person.filt.advance()
    mean, covariance = person.filt.predicted_measurement()
    joints = torch.einsum("ij,pjk->pik", torch.as_tensor(person.M, dtype=torch.float64),
                          person.filt.model.observe(person.filt.states).double())
    w = torch.exp(person.filt.log_weights).numpy()
    for c, camera in enumerate(person.cameras):
        uv = camera.project(joints)[0].numpy()                                    # (P, 15, 2)
        m = np.einsum("i,ijc->jc", w, uv)
        r = uv - m
        np.testing.assert_allclose(mean[c], m, rtol=1e-6, atol=1e-3)             # the particles are float32
        np.testing.assert_allclose(covariance[c], np.einsum("i,ijc,ijd->jcd", w, r, r), rtol=1e-4, atol=1e-2)
        assert np.all(np.linalg.eigvalsh(covariance[c]) > 0)


def test_the_filters_undo_an_identity_swap_the_scene_tracker_made(demo):
    """The scene tracker's decisions with the two people's detections exchanged in camera 2 over frames
    40–70 (a swap, as a joint model makes at a crossing): every person's ukf-real filter, in lockstep, gives
    each tick's detections back to their owner, in every ticked frame; what each filter consumed is the
    run's observations afterwards."""
    scene, calibration = demo
    truth = _association(scene, calibration)
    swapped = _association(scene, calibration)
    swapped.slots[40:71, 2] = swapped.slots[40:71, 2, ::-1].copy()
    config = TrackConfig(fps=60)
    people = {p: prepared(swapped.detections_of(scene, p), calibration, "ukf-real", config) for p in range(2)}
    consumed = {p: [] for p in people}
    for p, run in people.items():
        correct = run.filt.correct
        run.filt.correct = lambda z, correct=correct, p=p: consumed[p].append(np.array(z)) or correct(z)
    index = schedule(scene.frames, 60.0, 30.0)
    fixed, tracks = reassociated(scene, swapped, people, index, 0.3)
    ticked = np.unique(index[index >= 0])
    swap = ticked[(ticked >= 40) & (ticked <= 70)]
    assert len(swap) >= 15
    np.testing.assert_array_equal(fixed.slots[swap], truth.slots[swap])
    started = max(len(index) - len(run.index) + KNOWN_FRAMES for run in people.values())
    later = ticked[ticked >= index[started]]
    np.testing.assert_array_equal(fixed.slots[later], truth.slots[later])
    for p, run in people.items():
        first = len(run.z) - len(consumed[p])
        np.testing.assert_array_equal(np.stack(consumed[p]), run.z[first:])
        assert tracks[p].estimates.shape == (len(run.z), 15, 3)


def test_the_scene_of_the_filters_and_of_the_joint_model_agree_where_nothing_is_decided_otherwise(demo):
    """track_scene with association "filter" (the filters in lockstep, in this process) and "joints" (each
    person's run on its own):
    on the demo the filters decide no detection otherwise, and each person's joints are the same run's."""
    scene, calibration = demo
    by = {a: track_scene(scene, calibration, "ukf-real", TrackConfig(fps=60), SceneConfig(association=a), workers=1)
          for a in ("filter", "joints")}
    np.testing.assert_array_equal(by["filter"].association.slots, by["joints"].association.slots)
    np.testing.assert_allclose(by["filter"].joints, by["joints"].joints, atol=1e-9)



def test_the_filters_association_from_the_command_line_an_interrupt_and_a_filter_that_cannot_predict(demo, tmp_path,
                                                                                                      capsys, caplog):
    """``track --people all --association filter``: both people, their files, the log line counting the decisions
    changed; Ctrl-C during the lockstep (interruptible) ends every run at the tick reached; a fixed-lag smoother,
    which would smooth with detections not yet decided, refused; the MAP tracker, which has no prediction of its
    detections, is said not to predict."""
    import json
    import logging

    from priortrack.cli.main import main

    from test_scene import POSE as pose, QCA as qca

    with caplog.at_level(logging.INFO, logger="priortrack.tracking.reassociation"):
        assert main(["track", "--detections", str(pose), "--cameras", str(qca), "--keypoints", "body25b", "--fps", "60",
                     "--filter", "ukf-real", "--people", "all", "--association", "filter", "--frames", "40",
                     "--out", str(tmp_path / "s.npz"), "--json"]) == 0
    assert json.loads(capsys.readouterr().out.splitlines()[-1])["people"] == [0, 1]
    assert any("person-frames decided otherwise than the scene tracker's" in r.getMessage() for r in caplog.records)
    with np.load(tmp_path / "s.npz") as f:
        assert f["joints"].shape[1:] == (2, 15, 3) and np.isfinite(f["joints"]).any(axis=(0, 2, 3)).all()

    scene, calibration = demo

    def interrupt(tick, ticks):
        if tick == 20:
            raise KeyboardInterrupt

    result = track_scene(scene, calibration, "ukf-real", TrackConfig(fps=60, interruptible=True),
                         SceneConfig(association="filter"), progress=interrupt)
    assert all(person.interrupted and len(person.joints) < 25 for person in result.people)
    with pytest.raises(KeyboardInterrupt):
        track_scene(scene, calibration, "ukf-real", TrackConfig(fps=60), SceneConfig(association="filter"),
                    progress=interrupt)
    with pytest.raises(PriortrackError, match="smooth the whole run .--smooth without --lag."):
        track_scene(scene, calibration, "ukf-real", TrackConfig(fps=60, smooth=True, lag=5),
                    SceneConfig(association="filter"))
    assert not predicts(load_preset("map-gpdm")) and predicts(load_preset("ukf-real"))


def test_what_no_filter_takes_stays_the_scene_trackers():
    """One camera, three slots: person 0's filter wants slot 1, person 1's filter has lost its person (no slot within
    its gate), person 2 is not deciding (not started) and holds slot 2. Person 1 keeps the scene tracker's slot 0,
    which no filter took, instead of nothing (a filter given nothing does not come back); where person 0's filter
    takes person 1's slot, person 1 gets nothing."""
    from priortrack.tracking.reassociation import assigned

    slots = np.array([[1, 0, 2]])                                           # (C, P): the scene tracker's
    lost = np.full((1, 3), np.inf)
    wants_1 = np.array([[np.inf, 1.0, np.inf]])
    assert assigned({0: wants_1, 1: lost}, slots, 13.8).tolist() == [[1, 0, 2]]
    wants_0 = np.array([[1.0, np.inf, np.inf]])
    assert assigned({0: wants_0, 1: lost}, slots, 13.8).tolist() == [[0, -1, 2]]
    # a filter whose prediction is out of the camera's view keeps nothing there
    assert assigned({0: wants_1, 1: lost}, slots, 13.8, {0: np.array([True]), 1: np.array([False])}).tolist() == \
        [[1, -1, 2]]


def test_a_prediction_is_in_a_cameras_view_where_its_median_point_is_in_the_widened_image():
    """detection_costs' view: the median of the predicted points inside the image widened by IN_VIEW_MARGIN each
    side; a prediction wholly behind a camera (NaN) is in no view. Shelf, cameras 0, 1, 4: a filter 6 m out of the
    room had been handed a detection at 100,000 px."""
    from types import SimpleNamespace

    from priortrack.tracking.reassociation import IN_VIEW_MARGIN, detection_costs

    camera = SimpleNamespace(width=1000, height=800)
    mean = np.full((5, 15, 2), np.nan)                                        # camera 4: every point behind it
    mean[0] = [500.0, 400.0]                                                  # the image's centre
    mean[1] = [1000 + 0.9 * IN_VIEW_MARGIN * 1000, 400.0]                     # just beyond, within the margin
    mean[2] = [500.0, 800 + 1.1 * IN_VIEW_MARGIN * 800]                       # beyond the margin
    mean[3, :7] = [500.0, 400.0]                                              # 7 points, 8 behind the camera: NaN
    filt = SimpleNamespace(predicted_measurement=lambda: (mean, np.tile(np.eye(2), (5, 15, 1, 1))),
                           model=SimpleNamespace(likelihood=SimpleNamespace(cameras=[camera] * 5)))
    uv = np.full((5, 1, 15, 2), 500.0)
    costs, in_view = detection_costs(SimpleNamespace(filt=filt), uv, np.ones((5, 1, 15)))
    assert costs.shape == (5, 1) and np.isfinite(costs[0, 0])
    assert in_view.tolist() == [True, True, False, True, False]


def test_a_second_filter_on_one_person_is_found_after_half_a_second():
    """Three runs: people 0 and 1 at the same place, person 2 a metre off. After ``needed`` ticks together the later
    started of 0 and 1 (person 1) is a second track of one person, not before, and person 2 never; a tick apart resets
    the count."""
    from types import SimpleNamespace

    from priortrack.tracking.reassociation import _duplicates

    body = np.random.default_rng(0).normal(0, 0.3, (15, 3))
    runs = {p: SimpleNamespace(estimates=np.tile(body + [d, 0, 0], (5, 1, 1)), done=5)
            for p, d in ((0, 0.0), (1, 0.05), (2, 1.0))}
    first, together, ids = {0: 0, 1: 30, 2: 10}, {}, np.array([7, 8, 9])
    assert _duplicates([0, 1, 2], runs, first, together, 3, ids) == set()
    assert _duplicates([0, 1, 2], runs, first, together, 3, ids) == set()
    runs[1].estimates[-1] += [0.5, 0, 0]                                   # apart for a tick
    assert _duplicates([0, 1, 2], runs, first, together, 3, ids) == set() and together[0, 1] == 0
    runs[1].estimates[-1] -= [0.5, 0, 0]
    for _ in range(2):
        assert _duplicates([0, 1, 2], runs, first, together, 3, ids) == set()
    assert _duplicates([0, 1, 2], runs, first, together, 3, ids) == {1}


def test_a_filter_that_starts_on_someone_elses_person_is_a_second_track_at_once():
    """Person 1's filter starts (its first running tick, ``KNOWN_FRAMES`` after its first) 5 cm from person 0's latest
    estimate: a second track of person 0 before the two compete for one person's detections; person 2, started a
    metre off, and person 0 (older) are not; a person already running longer is not judged again (that is
    :func:`_duplicates`' half second)."""
    from types import SimpleNamespace

    from priortrack.tracking.reassociation import _born_on_someone

    body = np.random.default_rng(1).normal(0, 0.3, (15, 3))
    runs = {p: SimpleNamespace(estimates=np.tile(body + [d, 0, 0], (6, 1, 1)), done=done)
            for p, d, done in ((0, 0.0, 6), (1, 0.05, KNOWN_FRAMES), (2, 1.0, KNOWN_FRAMES))}
    first, ids = {0: 0, 1: 20, 2: 20}, np.array([7, 8, 9])
    k = 20 + KNOWN_FRAMES
    assert _born_on_someone([0, 1, 2], k, runs, first, ids) == {1}
    assert _born_on_someone([0, 1, 2], k + 1, runs, first, ids) == set()
    runs[1].estimates[KNOWN_FRAMES - 1] += [0.3, 0, 0]                     # its start 35 cm off: someone else
    assert _born_on_someone([0, 1, 2], k, runs, first, ids) == set()
