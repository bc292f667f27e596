"""Gaussian diffusion priors, state spaces and the prior file format."""

import json
import math

import numpy as np
import pytest
import torch

from priortrack import PriortrackError, load_motion, load_walkjog
from priortrack.priors import Diffusion, load_prior
from priortrack.priors.base import prepare_motions
from priortrack.priors.spaces import AngleSpace, DirectionSpace
from priortrack.body.fk import joint_positions
from priortrack.data.motion import Motion


@pytest.fixture(scope="module")
def walks():
    return list(load_walkjog().walks("train")[:6])


@pytest.mark.parametrize("space", ["angles", "directions"])
def test_local_sigma_is_the_maximum_likelihood_estimate(walks, space):
    model = Diffusion.fit(walks, local=True, space=space)
    steps = torch.cat([model.space.boxminus(x[1:], x[:-1]) for x in map(model.encode, walks)])
    sq = model.space.group_norms_sq(steps)                        # (N, G)
    dims = torch.as_tensor(model.space.tangent_dims, dtype=torch.float64)
    torch.testing.assert_close(model.sigma ** 2, sq.mean(0) / dims)
    # The likelihood is maximal there: scaling any σ down or up lowers it.
    x = torch.cat([m[:-1] for m in map(model.encode, walks)])
    y = torch.cat([m[1:] for m in map(model.encode, walks)])
    best = model.log_prob(y, x).sum()
    for factor in (0.9, 1.1):
        other = Diffusion(model.space, (model.sigma * factor).numpy(), True)
        assert other.log_prob(y, x).sum() < best


def test_global_sigma_pools_every_dimension(walks):
    model = Diffusion.fit(walks, local=False)
    assert model.kind == "diffusion-global" and torch.all(model.sigma == model.sigma[0])
    d = torch.cat([(x[1:] - x[:-1]) for x in map(model.encode, walks)])
    assert model.sigma[0].item() == pytest.approx(math.sqrt((d ** 2).mean().item()), rel=1e-12)


def test_angle_log_prob_is_the_gaussian_density(walks):
    model = Diffusion.fit(walks, local=True)
    x = model.encode(walks[0])[:5]
    y = model.encode(walks[0])[1:6]
    std = model.sigma[torch.as_tensor(model.space.groups)]
    expected = torch.distributions.Normal(x, std).log_prob(y).sum(-1)
    torch.testing.assert_close(model.log_prob(y, x), expected)


def test_sphere_diffusion_samples_stay_on_spheres_with_the_right_spread(walks):
    model = Diffusion.fit(walks, local=True, space="directions")
    x0 = model.encode(walks[0])[10]
    g = torch.Generator().manual_seed(3)
    x = model.sample(x0.expand(20000, -1).contiguous(), g)
    spheres = x.reshape(-1, 14, 3)
    assert (spheres.norm(dim=-1) - 1).abs().max() < 1e-12
    steps = model.space.boxminus(x, x0.expand_as(x))
    per_bone = model.space.group_norms_sq(steps).mean(0)           # E|v_b|² = 2σ_b²
    torch.testing.assert_close(per_bone, 2 * model.sigma ** 2, rtol=0.04, atol=0)


def test_seeded_sampling_and_initial(walks):
    model = Diffusion.fit(walks, local=True)
    x0 = model.encode(walks[1])[0]
    a = model.initial(x0, 50, torch.Generator().manual_seed(7))
    b = model.initial(x0, 50, torch.Generator().manual_seed(7))
    assert a.shape == (50, model.state_dim) and torch.equal(a, b)
    torch.testing.assert_close(a[0], x0)
    assert model.joints(a).shape == (50, 15, 3)


def test_joints_decode_the_training_pose(walks):
    angles = AngleSpace.fit(walks)
    m = walks[0]
    decoded = angles.joints(angles.encode(m))
    # The same pose with its root at the origin and no root rotation.
    truth = joint_positions(m, "eval15")
    truth_rel = truth - truth[:, :1]
    rel = (decoded - decoded[:, :1]).numpy()
    assert np.allclose(np.linalg.norm(rel, axis=-1), np.linalg.norm(truth_rel, axis=-1), atol=1e-9)
    directions = DirectionSpace.fit(walks)
    back = directions.joints(directions.encode(m))
    assert back.shape == (len(m), 15, 3)


@pytest.mark.parametrize("space", ["angles", "directions"])
def test_save_load_round_trip(tmp_path, walks, space):
    model = Diffusion.fit(walks, local=True, space=space)
    path = model.save(tmp_path / "prior.npz")
    loaded = load_prior(path)
    x = model.encode(walks[2])
    torch.testing.assert_close(loaded.log_prob(x[1:], x[:-1]), model.log_prob(x[1:], x[:-1]), rtol=0, atol=0)
    g1, g2 = torch.Generator().manual_seed(1), torch.Generator().manual_seed(1)
    torch.testing.assert_close(loaded.sample(x[:4], g1), model.sample(x[:4], g2), rtol=0, atol=0)
    assert loaded.kind == model.kind and loaded.fps == 30.0


def test_fit_resamples_120hz_motions_to_the_prior_rate():
    m = load_motion("cmu:07_01")
    model = Diffusion.fit([m], local=True)
    assert model.fps == 30.0
    assert model.encode(m).shape[0] == len(m.resample(30))


def test_bad_files(tmp_path, walks):
    model = Diffusion.fit(walks, local=False)
    path = model.save(tmp_path / "prior.npz")
    data = path.read_bytes()
    (tmp_path / "cut.npz").write_bytes(data[: len(data) // 2])
    with pytest.raises(PriortrackError, match="truncated"):
        load_prior(tmp_path / "cut.npz")
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files}
    header = json.loads(str(arrays["header"]))
    header["version"] = 99
    arrays["header"] = np.array(json.dumps(header))
    np.savez(tmp_path / "v99.npz", **arrays)
    with pytest.raises(PriortrackError, match="version 99"):
        load_prior(tmp_path / "v99.npz")
    header["version"] = "1"                         # a string is another version, and says so
    arrays["header"] = np.array(json.dumps(header))
    np.savez(tmp_path / "v1s.npz", **arrays)
    with pytest.raises(PriortrackError, match="version '1' is not supported"):
        load_prior(tmp_path / "v1s.npz")
    for text, message in (('{"format": "priortrack-prior", ', "header is not JSON"), ("[1, 2]", "header is a list")):
        np.savez(tmp_path / "badheader.npz", **{**arrays, "header": np.array(text)})
        with pytest.raises(PriortrackError, match=message):
            load_prior(tmp_path / "badheader.npz")
    del arrays["sigma"]
    header["version"] = 1
    arrays["header"] = np.array(json.dumps(header))
    np.savez(tmp_path / "nosigma.npz", **arrays)
    with pytest.raises(PriortrackError, match="sigma"):
        load_prior(tmp_path / "nosigma.npz")
    with pytest.raises(PriortrackError, match="does not exist"):
        load_prior(tmp_path / "none.npz")


def test_bad_training_data_and_states(walks):
    model = Diffusion.fit(walks, local=True)
    with pytest.raises(PriortrackError, match=r"expected \(P, 50\)"):
        model.sample(torch.zeros(3, 49), torch.Generator())
    with pytest.raises(PriortrackError, match="NaN"):
        model.log_prob(torch.full((2, 50), float("nan")), torch.zeros(2, 50))
    with pytest.raises(PriortrackError, match="x_next has 4 rows and x 3"):
        model.log_prob(torch.zeros(4, 50), torch.zeros(3, 50))
    on_spheres = Diffusion.fit(walks, space="directions")
    x = on_spheres.encode(walks[0])[:2]
    with pytest.raises(PriortrackError, match=r"not on the spheres: .* norms in \[2, 2\]"):
        on_spheres.sample(2 * x, torch.Generator())
    short = walks[0][:1]
    with pytest.raises(PriortrackError, match="frames"):
        prepare_motions([short], 30.0, min_frames=2)
    from dataclasses import replace
    bad = walks[0].channels.copy()
    bad[3, 10] = np.nan
    with pytest.raises(PriortrackError, match="NaN"):
        Diffusion.fit([replace(walks[0], channels=bad)])
    with pytest.raises(PriortrackError, match="unknown space"):
        Diffusion.fit(walks, space="quaternions")


def test_angle_prior_needs_one_channel_layout(tmp_path, walks):
    from priortrack.data.bvh import read_bvh, write_bvh

    write_bvh(walks[0], tmp_path / "walk.bvh")
    as_bvh = read_bvh(tmp_path / "walk.bvh")       # same body, ZXY channels on every joint
    with pytest.raises(PriortrackError, match="other channels"):
        Diffusion.fit([walks[1], as_bvh], space="angles")
    # The direction space only needs the eval15 joints: mixing layouts is fine there.
    assert Diffusion.fit([walks[1], as_bvh], space="directions").state_dim == 42


def test_a_body_keeps_its_own_posture_where_the_training_never_moves(walks):
    """CMU 35's clavicles never turn, so an angle prior does not model them; on a person's body (``for_body``) they are
    that person's: a walk with other shoulders decodes to its own joints (exactly, the root removed), where the
    training's posture puts the shoulders centimetres off."""
    angles = AngleSpace.fit(walks)
    names = walks[0].skeleton.channel_names
    clavicles = [names.index(n) for n in ("lclavicle.ry", "lclavicle.rz", "rclavicle.ry", "rclavicle.rz")]
    assert not set(clavicles) & set(angles.channels.tolist())          # the training never moves them
    channels = walks[0].channels.copy()
    channels[:, clavicles] += np.radians([12.0, -8.0, -10.0, 6.0])
    person = Motion(walks[0].skeleton, channels, walks[0].fps, "other shoulders")
    unrooted = person.channels.copy()
    root = [c for c in (*person.skeleton.rot_channels[0], *person.skeleton.trans_channels[0]) if c >= 0]
    unrooted[:, root] = 0.0
    truth = joint_positions(Motion(person.skeleton, unrooted, person.fps, "unrooted"), "eval15")
    truth = truth - truth[:, :1]
    body = angles.for_body(person)
    own = body.joints(body.encode(person)).numpy()
    np.testing.assert_allclose(own - own[:, :1], truth, atol=1e-9)
    training = angles.joints(angles.encode(person)).numpy()
    shoulders = np.linalg.norm((training - training[:, :1] - truth)[:, [3, 6]], axis=-1)
    assert shoulders.min() > 0.01
