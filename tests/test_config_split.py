"""The PPOConfig split (issue 33): PPOConfig (the algorithm), PolicyConfig (the policy's
parametrisation) and CurriculumConfig (training-only shaping) in one TrainConfig, with
the presets, old run folders and training results as before it (no compile here but the
policy's; the bitwise training checks ride on the suite's tiny trainings:
test_ppo.py's toy run and test_train_cli.py's tiny MARA run, both against PRESPLIT)."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import shutil
from pathlib import Path

import jax
import jax.numpy as jnp
import jaxlib
import numpy as np
import pytest

from mara_mjx.ppo import checkpoint as ckpt
from mara_mjx.ppo import config as config_module
from mara_mjx.ppo.config import (
    CurriculumConfig,
    PolicyConfig,
    PPOConfig,
    TrainConfig,
    upgrade_meta,
)
from mara_mjx.ppo.policy import load_policy
from mara_mjx.ppo.presets import PRESETS
from mara_mjx.runtime import runs

DATA = Path(__file__).parent / "data"
PRESPLIT = {
    # sha256 of the params and obs statistics after the tiny trainings, recorded with the
    # code before the split under the suite's compile flags and matmul precision
    # (tests/conftest.py; jax/jaxlib 0.10.2). `digest` and `checkpoint_digest` say how.
    # Compiled as users compile (no conftest flags) they were f7a2e50e... and 487ab280...
    # before the split and are the same after it. The bits depend on the CPU XLA compiles
    # for, not only on jax's version: one pair per kind of host they were recorded on.
    "versions": ("0.10.2", "0.10.2"),
    "hosts": {
        "the recording host (x86-64, 2026-11-27)": {
            "toy": "b24a013e1409afc5a057008838238651764cc6a14c08c812792ffc5e9467f6fc",
            "cli": "4b11559e0879ab98cd0f5ca1a0a9b56f1d4988b0eb2b201463acf76e6e442c0d",
        },
        # the recording commit (e0f3f82) gives this pair too on such a host: the host moved
        # the bits, not the code (benchmarks/NOTES.md section 60)
        "an Intel Xeon with AVX-512 and AMX (2026-12-07)": {
            "toy": "50d1e9cd91622b9105a064a50084f75c754cdb294614a01d253626e4f1589212",
            "cli": "08e05baa793f97fb55ea16fc7cb3f315b03586b1d09bf8fd6ec7860e039f5b98",
        },
        # the recording commit gives this pair too on such a host (AVX2 and FMA, no
        # AVX-512), as main does (and did with NOTES section 71's trace cuts applied)
        "an AMD EPYC with AVX2 (2026-12-08)": {
            "toy": "cb2b101637d451eb070ae24a910831b16e3af0216aba242b9ed91e476f5296d4",
            "cli": "4e24ab57e14961b3c72805c536cd0ef2182f6998ff998806dd78275c67768075",
        },
    },
}


def check_presplit(kind: str, got: str) -> None:
    """`got` (a digest of the tiny `kind` training, "toy" or "cli") is one of the pairs
    PRESPLIT recorded; else an AssertionError naming the hosts and what to do."""
    known = {host: pair[kind] for host, pair in PRESPLIT["hosts"].items()}
    assert got in known.values(), (
        f"the tiny {kind} training gave {got}, none of the bits recorded on {list(known)}: "
        "the training changed, or this is another kind of host (check with the recording "
        "commit e0f3f82 before adding it to PRESPLIT)"
    )


# tests/data/presplit_run (written before the split by `python -m mara_mjx.train --env
# MARA --num_envs 4 --num_steps 8 --total_timesteps 64 --num_minibatches 2
# --update_epochs 2 --max_episode_steps 16 --hidden_sizes 4`, preset ik_finish): its
# policy's actions at OBS, and at OBS with |e| inside the 6-cm finish, computed before the
# split (under the suite's flags, as above).
OBS = jnp.linspace(-0.5, 0.5, 12)  # float32, as recorded
ACTIONS = [
    [-0.5012491345405579, -0.4198797345161438, -0.31878989934921265]
    + [-0.225808247923851, -0.13125024735927582, -0.04454774037003517],
    [-0.5117917656898499, -0.44793227314949036, -0.3557387888431549]
    + [-0.22054524719715118, -0.17299430072307587, -0.045454517006874084],
]


def same_versions() -> bool:
    return (jax.__version__, jaxlib.__version__) == PRESPLIT["versions"]


def digest(tree) -> str:
    """sha256 of a pytree's leaves (their paths and bytes)."""
    h = hashlib.sha256()
    for path, leaf in jax.tree_util.tree_leaves_with_path(tree):
        h.update(jax.tree_util.keystr(path).encode())
        h.update(np.asarray(leaf).tobytes())
    return h.hexdigest()


def checkpoint_digest(path: Path) -> str:
    """sha256 of a checkpoint's params/ and obs_stats/ arrays (names and bytes)."""
    arrays, _ = ckpt.load_checkpoint(path)
    h = hashlib.sha256()
    for name in sorted(arrays):
        if name.startswith(("params/", "obs_stats/")):
            h.update(name.encode())
            h.update(np.asarray(arrays[name]).tobytes())
    return h.hexdigest()


def test_sections_hold_every_field_once_and_ppo_config_is_the_algorithm():
    sizes = {cls: len(dataclasses.fields(cls)) for cls in (PPOConfig, PolicyConfig)}
    assert sizes[PPOConfig] <= 25
    names = [
        f.name
        for cls in (PPOConfig, PolicyConfig, CurriculumConfig)
        for f in dataclasses.fields(cls)
    ]
    added = len(ADDED_SINCE_SPLIT)
    assert len(names) == len(set(names)) == 54 + added - len(config_module.REMOVED)


# The presets that deploy the plan and its restarts.
PLANNED = (
    "random_target_orient_plan",
    "random_target_plan",
    "random_target_plan_guard",
    "orient_first",
)

# Fields added after the split: (the default every pre-split config loads with, the
# presets that set another value and that value).
ADDED_SINCE_SPLIT = {
    "collision_guard_mm": (
        0.0,
        {"orient_first": 5.0, "orient_first_noisy_starts": 5.0, "random_target_plan_guard": 5.0},
    ),
    "plan_steps": (0, dict.fromkeys(PLANNED, 16)),
    "plan_starts": (0, dict.fromkeys(PLANNED, 16)),
    "commit_rad": (0.0, {}),
    "train_clearance_penalty": (0.0, {}),
    "train_clearance_mm": (10.0, {}),
    "train_clearance_points": (8, {}),
    "train_clearance_path": ("servo", {}),
    "train_capped_fraction": (0.0, {}),
    "train_capped_step": (0.025, {}),
    "teacher": ("", {}),
    "imitation_spread": (0.0, {}),
    "imitation_lookahead": (1, {}),
    "imitation_lookahead_mm": (20.0, {}),
    "train_reset_noise_final": (-1.0, {"orient_first_noisy_starts": 0.02}),
}


# Presets added after the split: the preset each one extends (its other fields).
PRESETS_SINCE_SPLIT = {
    "random_target_orient_plan": ("random_target_orient", {}),
    "random_target_plan": ("random_target_orient", {"total_timesteps": 50_000_000}),
    "random_target_plan_guard": ("random_target_orient", {"total_timesteps": 50_000_000}),
    "distill": ("random_target", {"hidden_sizes": [256, 256]}),  # its teacher: a flag
    "orient_first_noisy_starts": ("orient_first", {"train_reset_noise": 0.02}),
}


def test_every_preset_flattens_to_its_presplit_values():
    recorded = json.loads((DATA / "presplit_presets.json").read_text())["presets"]
    for name, (parent, changed) in PRESETS_SINCE_SPLIT.items():
        recorded[name] = {**recorded[parent], **changed}
    assert set(recorded) == set(PRESETS)
    for name, preset in PRESETS.items():
        flat = preset.flat()
        for field, (default, changed) in ADDED_SINCE_SPLIT.items():
            assert flat.pop(field) == changed.get(name, default), (name, field)
        assert flat == recorded[name], name
        loaded = TrainConfig.from_dict(recorded[name])  # the flat layout loads
        assert loaded.flat() == {**recorded[name], **{
            f: d for f, (d, _) in ADDED_SINCE_SPLIT.items()}}  # fmt: skip
        assert TrainConfig.from_dict(preset.to_dict()) == preset


def test_replace_routes_each_field_to_its_section():
    config = TrainConfig.of(num_envs=8, num_steps=4, num_minibatches=2, relative_actions=True)
    config = config.replace(ik_finish=0.06, population=3)
    assert (config.ppo.num_envs, config.policy.ik_finish, config.curriculum.population) == (
        8,
        0.06,
        3,
    )
    with pytest.raises(ValueError, match="unknown PPOConfig, PolicyConfig or CurriculumConfig"):
        config.replace(bogus=1)
    with pytest.raises(ValueError, match="ik_finish=0.06 replaces"):  # its section validates
        TrainConfig.of(ik_finish=0.06)


def test_removed_fields_load_at_their_default_and_are_named_otherwise(monkeypatch):
    monkeypatch.setitem(config_module.REMOVED, "old_switch", False)
    flat = {**PRESETS["cpu"].flat(), "old_switch": False}
    assert TrainConfig.from_dict(flat) == PRESETS["cpu"]
    with pytest.raises(ValueError, match="old_switch=True"):
        TrainConfig.from_dict({**flat, "old_switch": True})
    with pytest.raises(ValueError, match="unknown PPOConfig field"):
        TrainConfig.from_dict({**flat, "never_was": 1})


def test_a_presplit_run_folder_loads_evaluates_and_resumes_as_before(tmp_path):
    """The pre-split fixture: config.json and checkpoint with every field flat under
    "ppo". load_policy (evaluate, play, export, the gymnasium adapter) gives the actions
    it gave before the split; the resume path reads the same config from it and accepts
    the folder's old config.json as the same run's."""
    run = tmp_path / "run"
    shutil.copytree(DATA / "presplit_run", run)
    old = json.loads((run / "config.json").read_text())
    assert "policy" not in old and "ik_finish" in old["ppo"]  # truly the old layout
    policy = load_policy(run)
    assert policy.config.policy.ik_finish == 0.06 and policy.config.ppo.hidden_sizes == (4,)
    near = OBS.at[6:9].set(0.01)  # |e| = 17 mm: inside the IK finish
    for obs, expected in zip((OBS, near), ACTIONS, strict=True):
        if same_versions():
            np.testing.assert_array_equal(np.asarray(policy(obs)), np.float32(expected))
        np.testing.assert_allclose(np.asarray(policy(obs)), expected, rtol=1e-5, atol=1e-6)
    _, meta = ckpt.load_checkpoint(ckpt.find_checkpoint(run))
    assert meta["policy"]["ik_finish"] == 0.06 and "ik_finish" not in meta["ppo"]
    assert TrainConfig.from_meta(meta) == TrainConfig.from_meta(old) == policy.config
    assert upgrade_meta(meta) == meta  # the present layout is left as is
    assert runs.differences(old, meta) == []  # the old config.json: the same run
