"""Policy export (numpy parity with make_policy) and the plotting CLI.

Checkpoints are built without training: ActorCritic params (randomised so the mean is
O(1), not the 0.01-gain init) and observation statistics, saved by the real
`save_checkpoint` with the metadata the training CLI writes.
"""

from __future__ import annotations

import csv
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import mara_mjx
from mara_mjx.cli.common import run_cli
from mara_mjx.cli.export import ExportError, load_exported
from mara_mjx.cli.export import main as export_main
from mara_mjx.ppo import RunningStats, make_policy
from mara_mjx.ppo import checkpoint as ckpt
from mara_mjx.ppo.config import TrainConfig, for_env
from mara_mjx.ppo.networks import make_network
from mara_mjx.viz.plots import main as plots_main

PNG = b"\x89PNG\r\n\x1a\n"


def _run(module: str, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", module, *args], capture_output=True, text=True, timeout=120
    )


def make_run(folder, env_name: str, normalize: bool, seed: int = 0, relative: bool = False, **ppo):
    """A run folder with one checkpoint of random (untrained) params; returns its path.
    `ppo`: further PPOConfig fields; `constant_actor=True` zeroes the actor's last kernel
    (its output is its bias, whatever the observation)."""
    constant = ppo.pop("constant_actor", False)
    env = mara_mjx.make(env_name)
    config = TrainConfig.of(
        hidden_sizes=(32, 16),
        normalize_obs=normalize,
        obs_clip=5.0,
        relative_actions=relative,
        # the TCP velocity (MARAOrient's 13-15, MARA's 9-11)
        hidden_obs=((13, 14, 15) if "Orient" in env_name else (9, 10, 11)) if relative else (),
        # MARAOrient: the export must flip quat_err's sign too
        **{"canonical_quat": relative, **ppo},
    )
    config = for_env(config, env)
    network = make_network(config, env.action_size)
    key, init_key, noise_key, stats_key = jax.random.split(jax.random.key(seed), 4)
    obs = jnp.zeros(env.observation_size)
    params = network.init(init_key, obs, obs)
    leaves, treedef = jax.tree.flatten(params)
    keys = jax.random.split(noise_key, len(leaves))
    params = jax.tree.unflatten(
        treedef, [0.5 * jax.random.normal(k, x.shape) for k, x in zip(keys, leaves, strict=True)]
    )
    if constant:
        last = params["params"]["actor"][f"Dense_{len(config.ppo.hidden_sizes)}"]
        last["kernel"] = jnp.zeros_like(last["kernel"])
    state = {"params": params}
    if normalize:
        mean_key, var_key = jax.random.split(stats_key)
        state["obs_stats"] = RunningStats(
            mean=jax.random.normal(mean_key, (env.observation_size,)),
            var=jax.random.uniform(var_key, (env.observation_size,), minval=0.01, maxval=4.0),
            count=jnp.array(1000.0, jnp.float32),
        )
    meta = {
        "env_name": env_name,
        "env_config": env.config.to_dict(),
        "observation_size": env.observation_size,
        "action_size": env.action_size,
        **config.to_dict(),
        "run": {},
        "eval": {},
        "progress": {"update": 3, "env_steps": 300},
    }
    return ckpt.save_checkpoint(folder / "checkpoints" / ckpt.checkpoint_name(3), state, meta)


@pytest.mark.parametrize(
    ("env_name", "normalize", "relative", "step"),
    [("MARA", True, False, 0.0), ("MARAOrient", False, True, 0.05)],
)
def test_export_matches_make_policy(tmp_path, env_name, normalize, relative, step):
    path = make_run(tmp_path / "run", env_name, normalize, relative=relative, max_joint_step=step)
    out = tmp_path / "policy.npz"
    from mara_mjx.cli.export import export_policy

    export_policy(tmp_path / "run", out)  # a run folder: its newest checkpoint
    policy = load_exported(out)
    reference = make_policy(path)
    assert (reference.obs_stats is not None) == normalize
    assert (policy.obs_mean is not None) == normalize
    assert policy.meta["relative_actions"] == relative

    size = policy.observation_size
    assert size == (16 if "Orient" in env_name else 12)
    obs = np.random.default_rng(1).normal(0.0, 3.0, (64, size)).astype(np.float32)
    obs[:4] *= 100.0  # normalised values beyond obs_clip: the clip must match too
    expected = np.asarray(reference(jnp.asarray(obs)))
    got = policy(obs)
    assert got.shape == (64, 6) and got.dtype == np.float32
    assert np.abs(expected).max() > 0.1  # not the near-zero init: the check has teeth
    np.testing.assert_allclose(got, expected, atol=1e-5, rtol=1e-6)
    np.testing.assert_allclose(policy(obs[0]), expected[0], atol=1e-5, rtol=1e-6)
    assert policy.meta["max_joint_step"] == step
    if step:  # max_joint_step: every joint target within step of the observed joints
        moved = np.abs(got - obs[:, :6])
        assert 0.5 * step < moved.max() <= step + 1e-4  # float32 rounding of q + d - q

    env = mara_mjx.make(env_name)
    np.testing.assert_array_equal(policy.joint_lower, env.joint_lower.astype(np.float32))
    clipped = policy(obs, clip=True)
    assert np.all(clipped >= policy.joint_lower) and np.all(clipped <= policy.joint_upper)
    assert policy.meta["action"]["joint_names"][0] == "motor1"
    assert policy.meta["action"]["units"] == "rad"
    layout = policy.observation_layout
    assert layout["q"] == slice(0, 6) and layout["e"] == slice(6, 9)
    assert ("quat_err" in layout) == ("Orient" in env_name)
    assert layout["v"].stop == size
    assert policy.meta["env_config"]["max_episode_steps"] == 1024
    assert policy.meta["source"]["update"] == 3

    with pytest.raises(ValueError, match=rf"\(\.\.\., {size}\)"):
        policy(np.zeros(size + 1))
    with pytest.raises(ValueError, match="numeric"):
        policy(np.array(["x"] * size))


def test_export_refuses_task_space_policies(tmp_path):
    """A task_space_actions policy needs the arm's Jacobian: a clear ExportError, nothing
    written."""
    from mara_mjx.cli.export import ExportError, export_policy

    make_run(tmp_path / "run", "MARA", True, relative=True, task_space_actions=True)
    with pytest.raises(ExportError, match="task_space_actions"):
        export_policy(tmp_path / "run", tmp_path / "policy.npz")
    assert not (tmp_path / "policy.npz").exists()


def test_export_cli(tmp_path, capsys):
    make_run(tmp_path / "run", "MARA", True)
    out = tmp_path / "exported" / "policy.npz"
    result = _run("mara_mjx.export", str(tmp_path / "run"), str(out))
    assert result.returncode == 0, result.stderr
    assert "with observation normalisation" in result.stdout
    assert load_exported(out).env_name == "MARA"

    corrupt = tmp_path / "corrupt.npz"
    corrupt.write_bytes(b"not a zip file")
    blocker = tmp_path / "a_file"
    blocker.write_text("")
    (tmp_path / "empty_dir_is_no_run").mkdir()
    cases = [
        ([str(tmp_path / "missing"), str(out)], "does not exist"),
        ([str(tmp_path / "empty_dir_is_no_run"), str(out)], "no checkpoints"),
        ([str(corrupt), str(out)], "corrupt"),
        ([str(tmp_path / "run"), str(blocker / "policy.npz")], "cannot write"),
        ([str(tmp_path / "run"), str(tmp_path / "policy.txt")], "must end in .npz"),
    ]
    for argv, match in cases:
        assert run_cli(export_main, "export", argv) == 2, argv
        err = capsys.readouterr().err
        assert err.startswith("export: error:") and match in err, err

    with pytest.raises(ExportError, match="does not exist"):
        load_exported(tmp_path / "nope.npz")
    with pytest.raises(ExportError, match="corrupt"):
        load_exported(corrupt)
    ckpt_file = ckpt.find_checkpoint(tmp_path / "run")
    with pytest.raises(ExportError, match="format"):
        load_exported(ckpt_file)  # a checkpoint is not an exported policy


def test_export_never_writes_onto_a_checkpoint(tmp_path, capsys):
    """`export CKPT CKPT`, onto another run's checkpoint or into a checkpoints/ folder:
    exit 2, the checkpoint intact (it still loads and resumes)."""
    source = make_run(tmp_path / "run", "MARA", True)
    other = make_run(tmp_path / "other", "MARA", False, seed=1)
    before = {p: p.read_bytes() for p in (source, other)}
    cases = [
        ([str(source), str(source)], "is inside a run's checkpoints/"),
        ([str(tmp_path / "run"), str(other)], "is inside a run's checkpoints/"),
        ([str(source), str(source.parent / "policy.npz")], "is inside a run's checkpoints/"),
    ]
    moved = tmp_path / "ckpt_copy.npz"  # a checkpoint outside any checkpoints/ folder
    moved.write_bytes(other.read_bytes())
    cases.append(([str(source), str(moved)], "is a training checkpoint"))
    for argv, match in cases:
        assert run_cli(export_main, "export", argv) == 2, argv
        err = capsys.readouterr().err
        assert match in err, err
    assert {p: p.read_bytes() for p in (source, other)} == before
    assert not (source.parent / "policy.npz").exists()
    ckpt.load_checkpoint(moved)  # untouched
    # an existing exported policy may be replaced
    out = tmp_path / "policy.npz"
    assert run_cli(export_main, "export", [str(source), str(out)]) == 0
    assert run_cli(export_main, "export", [str(tmp_path / "other"), str(out)]) == 0
    assert load_exported(out).obs_mean is None  # the second (unnormalised) run's


def test_truncated_newest_checkpoint_falls_back_to_an_intact_one(tmp_path):
    older = make_run(tmp_path / "run", "MARA", True)
    newer = older.with_name(ckpt.checkpoint_name(7))
    newer.write_bytes(older.read_bytes()[:-100])  # a crash or a full disk
    messages = []
    found = ckpt.find_checkpoint(tmp_path / "run", warn=messages.append)
    assert found == older
    assert len(messages) == 1 and newer.name in messages[0] and str(older) in messages[0]
    policy = make_policy(str(tmp_path / "run"))  # the loaders use it too
    assert policy.obs_stats is not None
    result = _run("mara_mjx.export", str(tmp_path / "run"), str(tmp_path / "p.npz"))
    assert result.returncode == 0, result.stderr
    assert f"using {older}" in result.stderr
    older.write_bytes(b"also broken")
    with pytest.raises(ckpt.CheckpointError, match="no checkpoint .* is readable"):
        ckpt.find_checkpoint(tmp_path / "run", warn=messages.append)


def test_reward_shape_cli(tmp_path):
    out = tmp_path / "figs" / "reward_shape.png"
    result = _run("mara_mjx.plots", "reward-shape", "--out", str(out))
    assert result.returncode == 0, result.stderr
    data = out.read_bytes()
    assert data.startswith(PNG) and len(data) > 20_000


def _write_progress(folder, steps: int = 5, columns=("env_steps", "reward_mean", "entropy")):
    folder.mkdir(parents=True)
    with open(folder / "progress.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=["update", *columns])
        writer.writeheader()
        for i in range(steps):
            row = {"update": i + 1, "env_steps": 1000 * (i + 1)}
            row.update({"reward_mean": -1.0 + 0.2 * i, "entropy": 8.5 - 0.1 * i})
            writer.writerow({k: v for k, v in row.items() if k in ("update", *columns)})


def test_curves_cli(tmp_path, capsys):
    _write_progress(tmp_path / "run_a")
    _write_progress(tmp_path / "run_b", steps=3)
    out = tmp_path / "curves.png"
    runs = [str(tmp_path / "run_a"), str(tmp_path / "run_b")]
    assert plots_main(["curves", *runs, "--out", str(out)]) == 0
    data = out.read_bytes()
    assert data.startswith(PNG) and len(data) > 10_000

    _write_progress(tmp_path / "no_entropy", columns=("env_steps", "reward_mean"))
    (tmp_path / "empty_run").mkdir()
    _write_progress(tmp_path / "no_rows", steps=0)
    blocker = tmp_path / "a_file"
    blocker.write_text("")
    cases = [
        (["curves", str(tmp_path / "missing")], "does not exist"),
        (["curves", str(tmp_path / "empty_run")], "no progress.csv"),
        (["curves", str(tmp_path / "no_entropy")], "['entropy']"),
        (["curves", str(tmp_path / "no_rows")], "no rows"),
        (["curves", str(tmp_path / "run_a"), "--out", str(blocker / "x.png")], "cannot write"),
        (["reward-shape", "--out", str(blocker / "x.png")], "cannot write"),
    ]
    for argv, match in cases:
        assert run_cli(plots_main, "plots", argv) == 2, argv
        err = capsys.readouterr().err
        assert err.startswith("plots: error:") and match in err, err


def test_export_refuses_ik_prior_policies(tmp_path):
    """An ik_prior policy's inputs need the arm's Jacobian: a clear ExportError."""
    from mara_mjx.cli.export import ExportError, export_policy

    make_run(tmp_path / "run", "MARA", True, relative=True, ik_prior="residual")
    with pytest.raises(ExportError, match="ik_prior"):
        export_policy(tmp_path / "run", tmp_path / "policy.npz")
    assert not (tmp_path / "policy.npz").exists()


def test_export_keeps_the_ik_finish_in_npz_and_drops_it_on_request(tmp_path, capsys):
    """The position tasks' presets end with an IK finish (PPOConfig.ik_finish). The .npz
    keeps it (the arm's chain in its meta, mara_mjx/deploy/ik_numpy.py): the numpy policy equals
    the checkpoint's JAX policy far from the target, within the zone (the IK step) and
    where the learnt step jumps into it (the guard); --drop_ik_finish writes the learnt
    policy alone."""
    from mara_mjx.envs.task_space import nominal_chain

    path = make_run(tmp_path / "run", "MARA", True, relative=True, ik_finish=0.06)
    reference = make_policy(path)
    assert reference.network.ik_finish == 0.06
    rng = np.random.default_rng(2)
    obs = rng.normal(0.0, 1.0, (256, 12)).astype(np.float32)
    obs[:, :6] = rng.uniform(-1.5, 1.5, (256, 6))  # inside the joint limits
    direction = rng.normal(size=(256, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    obs[:, 6:9] = direction * rng.uniform(0.0, 0.4, (256, 1))  # |e| up to 40 cm
    want = np.asarray(reference(jnp.asarray(obs)))

    out = tmp_path / "policy.npz"
    assert run_cli(export_main, "export", [str(tmp_path / "run"), str(out)]) == 0
    policy = load_exported(out)
    assert policy.meta["ik_finish"]["radius"] == 0.06 and policy.meta["ik_finish_dropped"] == 0
    assert policy.meta["format"] == "mara_mjx.export/2"  # a /1 reader refuses it
    np.testing.assert_allclose(policy(obs), want, atol=1e-4)
    np.testing.assert_allclose(policy(obs[7]), policy(obs[7:8])[0], atol=1e-6)  # one obs
    from mara_mjx.deploy import onnx_policy

    with pytest.raises(ValueError, match="--drop_ik_finish"):
        onnx_policy.build_model(policy)  # the graph cannot run the finish
    assert (np.linalg.norm(obs[:, 6:9], axis=1) < 0.06).sum() >= 10  # finish steps
    # where the learnt step jumps into the zone (the guard): an actor whose output is
    # its bias b, and targets where q + b puts the TCP (5-40 cm away)
    constant = make_run(tmp_path / "constant", "MARA", True, relative=True, ik_finish=0.06,
                        constant_actor=True)  # fmt: skip
    learnt = np.asarray(
        make_policy(constant).replace(config=reference.config.replace(ik_finish=0.0))(
            jnp.asarray(obs)
        )
    ) - obs[:, :6]  # fmt: skip
    assert np.ptp(learnt, axis=0).max() < 1e-5  # the same step everywhere
    chain = nominal_chain()
    land = np.asarray(jax.vmap(lambda q: chain.tcp(q)[0])(jnp.asarray(obs[:, :6] + learnt)))
    here = np.asarray(jax.vmap(lambda q: chain.tcp(q)[0])(jnp.asarray(obs[:, :6])))
    jumps = obs.copy()
    jumps[:, 6:9] = here - land  # the target where the step lands
    far = np.linalg.norm(jumps[:, 6:9], axis=1) > 0.07
    jumps = jumps[far]
    assert len(jumps) >= 20
    # and steps the joint limits clip: the arm joint the step moves most, 0.01 rad from
    # the stop it moves toward
    j = int(np.argmax(np.abs(learnt[0, :3])))
    edge = jumps[:8].copy()
    toward = policy.joint_lower[j] + 0.01 if learnt[0, j] < 0 else policy.joint_upper[j] - 0.01
    edge[:, j] = toward
    assert abs(learnt[0, j]) > 0.1  # the clip moves the landing point
    clipped = np.clip(edge[:, :6] + learnt[:8], policy.joint_lower, policy.joint_upper)
    land = np.asarray(jax.vmap(lambda q: chain.tcp(q)[0])(jnp.asarray(clipped)))
    here = np.asarray(jax.vmap(lambda q: chain.tcp(q)[0])(jnp.asarray(edge[:, :6])))
    edge[:, 6:9] = here - land
    jumps = np.concatenate([jumps, edge[np.linalg.norm(edge[:, 6:9], axis=1) > 0.07]])
    run_cli(export_main, "export", [str(tmp_path / "constant"), str(tmp_path / "c.npz")])
    guarded = load_exported(tmp_path / "c.npz")(jumps)
    np.testing.assert_allclose(guarded, np.asarray(make_policy(constant)(jnp.asarray(jumps))),
                               atol=1e-4)  # fmt: skip
    moved = guarded - jumps[:, :6]
    assert np.all(np.abs(moved).max(axis=1) < np.abs(learnt[0]).max() - 1e-3)  # cut

    # (.onnx keeps the finish in a graph traced from the JAX policy: deploy/onnx_graph.py)
    dropped = tmp_path / "learnt.npz"
    argv = [str(tmp_path / "run"), str(dropped), "--drop-ik-finish"]  # the old spelling
    assert run_cli(export_main, "export", argv) == 0
    assert "--drop-ik-finish is deprecated; use --drop_ik_finish" in capsys.readouterr().err
    alone = load_exported(dropped)
    assert alone.meta["ik_finish_dropped"] == 0.06 and "ik_finish" not in alone.meta
    assert alone.meta["format"] == "mara_mjx.export/1"
    far_obs = obs[np.linalg.norm(obs[:, 6:9], axis=1) > 0.06]
    np.testing.assert_allclose(alone(far_obs), policy(far_obs), atol=1e-4)  # no jumps here
    near_obs = obs[np.linalg.norm(obs[:, 6:9], axis=1) < 0.06]
    assert np.abs(alone(near_obs) - policy(near_obs)).max() > 1e-3  # no finish
