"""The exported training program (mara_mjx.ppo.trace_cache): a warm start loads it instead of
tracing, runs the same bits as the plain jitted `trainer.run`, compiles once for init's
state and its own, and never trusts a damaged or foreign file."""

import jax
import numpy as np
import pytest

import mara_mjx
from mara_mjx.ppo import PRESETS, make_train, trace_cache

CONFIG = PRESETS["default"].replace(
    num_envs=4, num_steps=4, num_minibatches=1, update_epochs=1, total_timesteps=64
)


def leaves(tree) -> list[np.ndarray]:
    def raw(x):
        if jax.dtypes.issubdtype(x.dtype, jax.dtypes.prng_key):
            return np.asarray(jax.random.key_data(x))
        return np.asarray(x)

    return [raw(x) for x in jax.tree.leaves(tree)]


@pytest.fixture(scope="module")
def env():
    return mara_mjx.make("MARA")


def trainer(env, config=CONFIG):
    return make_train(env, config, updates_per_call=2)


def test_warm_start_loads_and_runs_the_plain_programs_bits(env, tmp_path):
    key = jax.random.key(3)
    first = trainer(env)
    shapes = jax.eval_shape(first.init, key)
    run_cold, status = trace_cache.exported_run(first, shapes, tmp_path)
    assert status.startswith("exported "), status
    files = list(tmp_path.glob("*.bin"))
    assert len(files) == 1 and files[0].stat().st_size > 10_000

    # a new process builds a new trainer; the warm path never runs (traces) its `run`
    second = trainer(env)
    traced = []
    second = second._replace(run=lambda *a, run=second.run: traced.append(1) or run(*a))
    run_warm, status = trace_cache.exported_run(second, shapes, tmp_path)
    assert status == f"loaded {files[0]}"

    init = jax.jit(first.init, out_shardings=trace_cache.device_sharding())
    plain_state, plain_m = first.run(*first.run(first.init(key), 2)[:1], 1)
    # the plain init's state (uncommitted), then run's own (committed): one XLA compile
    start = first.init(key)
    compiles = []
    listening = [True]

    def listen(event: str, seconds: float, **_) -> None:
        if listening[0] and event == "/jax/core/compile/backend_compile_duration":
            compiles.append(seconds)

    jax.monitoring.register_event_duration_secs_listener(listen)
    try:
        state, m = run_cold(start, 2)
        state, m = run_cold(state, 1)
    finally:
        listening[0] = False
    assert len(compiles) == 1, compiles
    warm_state, warm_m = run_warm(run_warm(init(key), 2)[0], 1)
    runs = leaves((state, m)), leaves((warm_state, warm_m)), leaves((plain_state, plain_m))
    for a, b, c in zip(*runs, strict=True):
        np.testing.assert_array_equal(a, b)
        np.testing.assert_array_equal(a, c)
    assert set(m) == set(plain_m)
    assert traced == []


def test_the_key_follows_config_shapes_and_source(env, monkeypatch):
    t = trainer(env)
    shapes = jax.eval_shape(t.init, jax.random.key(0))
    base = trace_cache.cache_key(t, shapes)
    assert trace_cache.cache_key(trainer(env), shapes) == base
    assert trace_cache.cache_key(trainer(env, CONFIG.replace(seed=7)), shapes) == base
    assert trace_cache.cache_key(trainer(env, CONFIG.replace(learning_rate=1e-3)), shapes) != base
    wider = trainer(env, CONFIG.replace(num_envs=8))
    assert trace_cache.cache_key(wider, jax.eval_shape(wider.init, jax.random.key(0))) != base
    # a user's own variant: the same config and shapes, another task (reward, collisions)
    from mara_mjx.envs.mara import TASKS, MaraEnv, default_config

    own = MaraEnv(TASKS["MARACollision"], default_config(TASKS["MARA"]))
    assert own.config == env.config
    assert trace_cache.cache_key(trainer(own), shapes) != base
    monkeypatch.setattr(trace_cache, "source_hash", lambda: "edited")
    assert trace_cache.cache_key(t, shapes) != base


def test_a_damaged_file_is_exported_again_and_the_cache_can_be_off(
    env, tmp_path, capsys, monkeypatch
):
    t = trainer(env)
    shapes = jax.eval_shape(t.init, jax.random.key(0))
    path = tmp_path / f"{trace_cache.cache_key(t, shapes)}.bin"
    path.write_bytes(b"\x10\x00\x00\x00\x00\x00\x00\x00{not json at all}")
    run, status = trace_cache.exported_run(t, shapes, tmp_path)
    assert status.startswith("exported ") and f"ignoring {path}" in capsys.readouterr().err
    assert trace_cache.exported_run(t, shapes, tmp_path)[1].startswith("loaded ")
    # a readable program for other shapes (a wider batch) under this key: not used
    wider = trainer(env, CONFIG.replace(num_envs=8))
    other = tmp_path / "other"
    trace_cache.exported_run(wider, jax.eval_shape(wider.init, jax.random.key(0)), other)
    (foreign,) = other.glob("*.bin")
    path.write_bytes(foreign.read_bytes())
    assert trace_cache.exported_run(t, shapes, tmp_path)[1].startswith("exported ")
    assert "exported for another configuration" in capsys.readouterr().err
    # a folder that cannot be written: trains with the program all the same
    blocked = tmp_path / "a_file"
    blocked.write_text("")
    run, status = trace_cache.exported_run(t, shapes, blocked / "sub")
    assert status.startswith("exported (not saved") and run is not t.run
    assert trace_cache.exported_run(t, shapes, None) == (t.run, "off: no compilation cache")
    assert trace_cache.cache_folder(True, str(tmp_path)) == tmp_path / trace_cache.FOLDER
    assert trace_cache.cache_folder(False, str(tmp_path)) is None
    monkeypatch.setenv(trace_cache.ENV_VAR, "0")
    assert trace_cache.cache_folder(True, str(tmp_path)) is None


def test_swapped_entries_are_traced_again_not_trusted_by_name(env, tmp_path, capsys):
    """Two configurations' files with the same shapes, swapped: each run notices that the
    file under its name holds the other's program (its key material) and traces again."""
    a = trainer(env)
    b = trainer(env, CONFIG.replace(learning_rate=1e-3))  # same state shapes, other program
    shapes = jax.eval_shape(a.init, jax.random.key(0))
    path_a = tmp_path / f"{trace_cache.cache_key(a, shapes)}.bin"
    path_b = tmp_path / f"{trace_cache.cache_key(b, shapes)}.bin"
    assert path_a != path_b
    for t in (a, b):
        assert trace_cache.exported_run(t, shapes, tmp_path)[1].startswith("exported ")
    blob_a, blob_b = path_a.read_bytes(), path_b.read_bytes()
    path_a.write_bytes(blob_b)
    path_b.write_bytes(blob_a)
    capsys.readouterr()
    run, status = trace_cache.exported_run(a, shapes, tmp_path)
    assert status == f"exported {path_a}", status
    err = capsys.readouterr().err
    assert f"ignoring {path_a}" in err and "first at 'ppo'" in err, err
    assert path_a.read_bytes() != blob_b  # replaced by a's own program
    assert trace_cache.exported_run(a, shapes, tmp_path)[1] == f"loaded {path_a}"


def test_the_reach_probe_apart_is_kept_and_loaded_as_run_is(env, tmp_path):
    """make_train's probe_apart: the reach probe has its own cache file (its own key, and
    run's key says whether the probe is in run), a warm start loads it without tracing,
    and cold, warm and plain give the same bits."""
    config, key = CONFIG.replace(probe_reach_steps=2), jax.random.key(3)
    first = make_train(env, config, updates_per_call=2, probe_apart=True)
    shapes = jax.eval_shape(first.init, key)
    probe_cold, status = trace_cache.exported_probe(first, shapes, tmp_path)
    assert status.startswith("exported "), status
    second = make_train(env, config, updates_per_call=2, probe_apart=True)
    traced = []
    second = second._replace(probe=lambda *a, p=second.probe: traced.append(1) or p(*a))
    probe_warm, status = trace_cache.exported_probe(second, shapes, tmp_path)
    assert status.startswith("loaded ") and traced == [], status
    state = first.init(key)
    plain = np.asarray(first.probe(state, 2))
    assert np.isfinite(plain[1]) and np.isnan(plain[0])
    np.testing.assert_array_equal(np.asarray(probe_cold(state, 2)), plain)
    np.testing.assert_array_equal(np.asarray(probe_warm(state, 2)), plain)
    keys = {
        trace_cache.key_material(t, shapes, p)
        for t in (first, trainer(env))
        for p in ("run", "probe")
    }
    assert len(keys) == 4
