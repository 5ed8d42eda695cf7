"""The benchmark CLI (every study with --quick, as subprocesses) and the brax adapter.

All CLI runs start together when the module's first test asks for them, so that their
compiles overlap each other and the in-process tests. The `brax` study's work (brax's PPO
against ours) runs inside the `tta` study's peers part, whose records the brax test reads
and renders as the brax study's report (one brax training in the suite, not two).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from brax.envs.base import State
from brax.envs.wrappers.training import wrap

import mara_mjx
from mara_mjx.adapters.brax_env import METRICS, NEVER, BraxMaraEnv, make_brax_env
from mara_mjx.bench.ppo_runs import CompileClock, Run

ROOT = Path(__file__).resolve().parents[1]
META_KEYS = {"study", "command", "versions", "device", "config", "date", "records"}


def _cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "mara_mjx.benchmark", *args]


def _popen(args: list[str], **env: str) -> subprocess.Popen:
    env = {**os.environ, "JAX_PLATFORMS": "cpu", **env}
    return subprocess.Popen(
        args, cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
    )


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """Start every quick study at once (they overlap the in-process brax tests)."""
    out = tmp_path_factory.mktemp("bench")
    tiny = ["--quick", "--tasks", "MARA", "--out", str(out)]
    procs = {
        "env": _popen(_cli("env", *tiny, "--drivers", "train")),
        "peers": _popen(_cli("peers", "--quick", "--skip_mjx", "--out", str(out))),
        "limit": _popen(_cli("limit", *tiny, "--drivers", "train")),
        "tta": _popen(_cli("tta", *tiny)),
        "train": _popen(_cli("train", *tiny)),
    }
    return out, procs, {}


def _finish(runs, study: str) -> dict:
    """Wait for the study's process; check its files; its JSON (strict: no NaN)."""
    out, procs, texts = runs
    proc = procs[study]
    if proc not in texts:
        texts[proc] = proc.communicate(timeout=600)[0]
    assert proc.returncode == 0, texts[proc][-6000:]
    for ext in ("json", "md", "png"):
        assert (out / f"{study}.{ext}").is_file()

    def no_constant(name):
        raise AssertionError(f"{study}.json holds {name}")

    return json.loads((out / f"{study}.json").read_text(), parse_constant=no_constant)


# ----------------------------------------------------------------- brax adapter
@pytest.fixture(scope="module")
def brax_env(runs) -> BraxMaraEnv:  # `runs` first: the subprocesses start before compiling
    return make_brax_env("MARA")


def test_brax_adapter_matches_mara_env(brax_env):
    env = mara_mjx.make("MARA", max_episode_steps=NEVER)
    assert brax_env.observation_size == env.observation_size == 12
    assert brax_env.action_size == 6 and brax_env.backend == "mjx"
    a = jnp.array([-1.0, -0.5, 0.0, 0.25, 0.5, 1.0])
    q_cmd = brax_env.to_joint_targets(a)
    lo, hi = env.joint_lower, env.joint_upper
    np.testing.assert_allclose(q_cmd, lo + (a + 1) / 2 * (hi - lo), rtol=1e-6)

    @jax.jit
    def both(key):  # one compile: reset both, then two steps of each in a scan
        def body(carry, _):
            bs, es = carry
            bs, es = brax_env.step(bs, a), env.step(es, q_cmd)
            return (bs, es), (bs, es)

        first = (brax_env.reset(key), env.reset(key))
        return first, jax.lax.scan(body, first, None, length=2)[1]

    (bs0, es0), (bs, es) = both(jax.random.PRNGKey(3))
    assert isinstance(bs0, State)
    np.testing.assert_allclose(bs0.obs, es0.obs)
    assert set(bs.metrics) == set(METRICS)
    np.testing.assert_allclose(bs.obs, es.obs, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(bs.reward, es.reward, rtol=1e-5, atol=1e-6)
    np.testing.assert_array_equal(bs.done, 0.0)
    np.testing.assert_allclose(bs.metrics["distance"], es.metrics["distance"], rtol=1e-6)
    np.testing.assert_allclose(
        bs.metrics["position_error_y"], es.metrics["position_error"][:, 1], rtol=1e-6
    )
    assert all(v.shape == (2,) for v in bs.metrics.values())  # () per step, stacked


def test_brax_wrap_truncates_at_episode_length(brax_env):
    w = wrap(brax_env, episode_length=3)
    state = jax.jit(w.reset)(jax.random.split(jax.random.PRNGKey(0), 2))
    step = jax.jit(w.step)
    action = jnp.zeros((2, 6))
    dones, truncs = [], []
    for _ in range(4):
        state = step(state, action)
        dones.append(np.asarray(state.done).tolist())
        truncs.append(np.asarray(state.info["truncation"]).tolist())
    assert dones == [[0, 0], [0, 0], [1, 1], [0, 0]]  # done at the horizon, then auto-reset
    assert truncs == [[0, 0], [0, 0], [1, 1], [0, 0]]  # a truncation: brax's GAE bootstraps
    assert state.info["episode_metrics"]["distance"].shape == (2,)


def test_brax_adapter_rejects_mara_horizon():
    with pytest.raises(ValueError, match="episode_length"):
        make_brax_env("MARA", max_episode_steps=10)
    with pytest.raises(ValueError, match="episode_length"):
        make_brax_env("MARA", episode_length=0)
    with pytest.raises(ValueError, match="unknown env"):
        make_brax_env("NoSuchTask")


# ------------------------------------------------------------------- the CLI
def test_env_study_quick(runs):
    data = _finish(runs, "env")
    assert META_KEYS <= set(data) and data["study"] == "env"
    (rec,) = data["records"]
    assert rec["task"] == "MARA" and rec["driver"] == "train" and rec["num_envs"] == 4
    assert rec["env_steps_per_s"] > 0 and rec["physics_steps_per_s"] is None


def test_peers_study_quick(runs):
    data = _finish(runs, "peers")
    assert META_KEYS <= set(data) and data["study"] == "peers"
    kin, rec = data["records"]
    assert kin["impl"].startswith("mujoco C kinematics+collision") and kin["driver"] == "train"
    assert kin["num_envs"] == 4 and kin["env_steps_per_s"] > 0
    assert 0.0 <= kin["collision_fraction"] <= 1.0 and kin["median_call_s"] <= kin["wall_s"]
    assert rec["impl"].startswith("mujoco C rollout")
    assert rec["num_envs"] == 4 and rec["substeps"] == 10
    assert rec["physics_steps_per_s"] == pytest.approx(10 * rec["env_steps_per_s"])
    assert "mjx_over_c" in rec


CURVE_KEYS = {"t_s", "t_run_s", "compile_s", "env_steps", "settled_mm", "settled_axis_mm"}


def _check_run(rec: dict, impl: str) -> None:
    """A PPO run record of the quick settings: 2 calls of 1 update of 4 envs x 8 steps."""
    assert rec["task"] == "MARA" and rec["impl"].startswith(impl)
    assert rec["env_steps"] == 64 and rec["calls"] == 2 and rec["num_envs"] == 4
    assert rec["env_steps_per_s"] > 0 and rec["compile_s"] > 0 and rec["wall_s"] > 0
    assert [p["env_steps"] for p in rec["curve"]] == [0, 32, 64]
    for p in rec["curve"]:
        assert CURVE_KEYS <= set(p) and 0 <= p["t_run_s"] <= p["t_s"]
        assert p["settled_mm"] > 0 and len(p["settled_axis_mm"]) == 3
    for name in ("settled_to_5mm", "settled_to_1mm"):
        assert {f"{name}_s", f"{name}_wall_s", f"{name}_env_steps"} <= set(rec)
    assert rec["final_settled_mm"] == rec["curve"][-1]["settled_mm"]
    assert rec["score"] == {"episodes": 2, "steps": 8, "last": 4, "noise": 0.02, "seed": 0}


def test_train_study_quick(runs):
    data = _finish(runs, "train")
    assert META_KEYS <= set(data) and data["study"] == "train"
    assert data["settings"]["matmul_precision"] == "highest"
    (rec,) = data["records"]
    _check_run(rec, "ours")
    assert rec["preset"] == "default" and rec["ppo"]["num_envs"] == 4
    assert [p.get("det_error_mm") is not None for p in rec["curve"]] == [False, True, True]
    assert {"det_error_to_5mm_s", "det_error_to_1mm_s", "final_det_error_mm"} <= set(rec)
    for name, tolerance in (("eval_stop_5mm", 5.0), ("eval_horizon", 0.0)):
        ev = rec[name]
        assert ev["tolerance_mm"] == tolerance and ev["episodes"] == 2
        assert ev["mean_axis_error_mm"] > 0 and len(ev["position_error_mm"]) == 3
    assert rec["eval_horizon"]["steps"] == 16  # the quick horizon


def test_brax_study_quick(runs, tmp_path):
    """The brax study's records (`brax_study`, run by the tta study's peers part with the
    brax study's --quick settings) and its report written from them."""
    from mara_mjx.bench.runner import write_results

    data = _finish(runs, "tta")
    ours, theirs = [r for r in data["records"] if r["kind"] == "peer" and "curve" in r]
    paths = write_results("brax", [ours, theirs], tmp_path, data)
    assert all(p.stat().st_size > 0 for p in paths)
    assert "brax ppo" in paths[1].read_text() and "brax" in paths[1].read_text().splitlines()[0]
    _check_run(ours, "ours")
    _check_run(theirs, "brax")
    assert {"brax_over_ours_time_to_5mm", "ours_over_brax_env_steps_per_s"} <= set(ours)
    assert ours["ours_over_brax_env_steps_per_s"] == pytest.approx(
        ours["env_steps_per_s"] / theirs["env_steps_per_s"]
    )
    kw = theirs["brax_kwargs"]
    assert (kw["num_envs"], kw["unroll_length"], kw["batch_size"]) == (4, 8, 2)
    assert (kw["num_minibatches"], kw["num_updates_per_batch"]) == (2, 2)
    assert kw["entropy_cost"] == 0 and kw["reward_scaling"] == 0.01
    assert kw["normalize_observations"] and kw["episode_length"] == 16


def test_limit_study_quick(runs):
    data = _finish(runs, "limit")
    assert META_KEYS <= set(data) and data["study"] == "limit"
    (rec,) = data["records"]
    assert (rec["task"], rec["driver"], rec["num_envs"]) == ("MARA", "train", 4)
    positive = ("flops_per_env_step", "bytes_per_env_step", "f32_matmul_flops_per_s")
    positive += ("bf16_matmul_flops_per_s", "bytes_per_s", "env_steps_per_s")
    for key in positive:
        assert rec[key] > 0, key
    bound = min(
        rec["f32_matmul_flops_per_s"] / rec["flops_per_env_step"],
        rec["bytes_per_s"] / rec["bytes_per_env_step"],
    )
    assert rec["bound_env_steps_per_s"] == pytest.approx(bound)
    assert rec["limited_by"] in ("compute", "memory")
    assert rec["fraction_of_bound"] == pytest.approx(rec["env_steps_per_s"] / bound)


def test_tta_study_quick(runs):
    """The train CLI as a user runs it, cold then warm, with both settings of XLA's
    deterministic GPU ops, and the roofline of its env step."""
    data = _finish(runs, "tta")
    assert META_KEYS <= set(data) and data["study"] == "tta"
    assert data["settings"]["XLA_PYTHON_CLIENT_PREALLOCATE"] == "false"  # trainings share it
    records = data["records"]
    found = {(r["part"], r["cache"], r["xla_ops"]): r for r in records if r["kind"] == "run"}
    cold, warm = found["tta", "cold", "cli default"], found["tta", "warm", "cli default"]
    det = found["xla_ops", "off", "deterministic"]
    nondet = found["xla_ops", "off", "non-deterministic"]
    assert len(found) == 6
    for r in found.values():
        n = r.get("num_seeds", 1)
        assert r["task"] == "MARA" and r["seed"] == 0 and r["env_steps"] == 64 * n
        assert "python -m mara_mjx.train --env MARA --seed 0 " in r["command"]
        assert abs(r["launch_offset_s"]) < 1.0  # the child's start, read from /proc
        assert 0 < r["first_call_s"] <= r["cli_command_time_s"] <= r["command_s"]
        assert r["env_steps_per_s"] > 0 and len(r["state_hash"]) == 16
        assert len(r["training_hash"]) == 16 and r["training_hash"] != r["state_hash"]
        for mm in (5, 1):  # 64 env steps reach neither
            assert r[f"to_{mm}mm_s"] is None and r[f"to_{mm}mm_env_steps"] is None
    assert len({r["command"].split("--compilation_cache ")[1] for r in (cold, warm)}) == 1
    assert warm["same_bits_as_cold"] is True  # its programs from the cache: the same bits
    # --seeds 2 in one program: every seed's folder read, the rates summed, bitwise again
    group_cold = found["seeds", "cold", "cli default"]
    group_warm = found["seeds", "warm", "cli default"]
    assert "--seed 0 --seeds 2 " in group_warm["command"] and group_warm["num_seeds"] == 2
    assert [p["env_steps"] for p in group_warm["per_seed"]] == [64, 64]
    rates = [p["env_steps_per_s"] for p in group_warm["per_seed"]]
    assert group_warm["env_steps_per_s"] == sum(rates) and min(rates) > 0
    assert group_warm["same_bits_as_cold"] is True
    assert group_cold["state_hash"] == group_warm["state_hash"]
    assert cold["num_seeds"] == 1 and "--seeds" not in cold["command"]
    text = (runs[0] / "tta.md").read_text()
    assert "Several seeds in one program" in text and "2 seeds" in text
    assert "--xla_gpu_deterministic_ops=true" in det["xla_flags_given"]
    assert "--xla_gpu_deterministic_ops=false" in nondet["xla_flags_given"]
    assert "xla_gpu_deterministic_ops" not in cold["xla_flags_given"]  # the CLI chooses
    medians = [r for r in records if r["kind"] == "median"]
    assert [(m["cache"], m["seeds"], m["reached_1mm"]) for m in medians] == [
        ("cold", [0], 0),
        ("warm", [0], 0),
    ]
    assert medians[1]["command_s"] == warm["command_s"]
    (limit,) = [r for r in records if r["kind"] == "limit"]
    assert (limit["task"], limit["driver"], limit["num_envs"]) == ("MARA", "train", 4)
    assert limit["flops_per_env_step"] > 0 and limit["bytes_per_env_step"] > 0
    assert limit["ppo_env_steps_per_s"] == warm["env_steps_per_s"]
    assert limit["ppo_fraction_of_bound"] == pytest.approx(
        limit["ppo_env_steps_per_s"] / limit["bound_env_steps_per_s"]
    )
    # the peers on the same machine: C MuJoCo against the limit part's MJX step, brax's
    # PPO against ours (the brax study, same env steps)
    c_peer, *ppo = [r for r in records if r["kind"] == "peer"]
    assert c_peer["impl"].startswith("mujoco C") and c_peer["num_envs"] == 4
    assert c_peer["mjx_env_steps_per_s"] == limit["env_steps_per_s"]
    assert c_peer["mjx_over_c"] == pytest.approx(
        limit["env_steps_per_s"] / c_peer["env_steps_per_s"]
    )
    assert [r["impl"] for r in ppo] == ["ours (mara_mjx.ppo)", "brax ppo"]
    assert all(r["env_steps"] == 64 and r["env_steps_per_s"] > 0 for r in ppo)
    assert "C peer (mujoco C" in text and "PPO peers (`brax` study" in text


def test_tta_reads_the_cli_times_on_the_launch_clock(tmp_path):
    from mara_mjx.bench.train_command import read_run
    from mara_mjx.bench.tta import median_record

    rows = ["update,env_steps,time_s,steps_per_s,det_error_mm"]
    rows += ["1,10,4.0,2.0,9.0", "2,20,4.0,2.0,4.0", "3,30,5.0,100.0,2.0", "4,40,6.0,300.0,0.5"]
    (tmp_path / "progress.csv").write_text("\n".join(rows) + "\n")
    hit = {"time_s": 4.0, "env_steps": 20, "update": 2}
    summary = {"time_to_accuracy": {"5mm": hit}, "command_time_s": 7.0}
    (tmp_path / "summary.json").write_text(json.dumps(summary))
    r = read_run(tmp_path, offset=0.25)
    assert (r["to_5mm_s"], r["to_5mm_env_steps"], r["to_1mm_s"]) == (4.25, 20, None)
    assert (r["first_call_s"], r["cli_command_time_s"]) == (4.25, 7.25)
    assert r["env_steps_per_s"] == 200.0  # median of the rows after the first call
    assert r["final_det_error_mm"] == 0.5 and r["state_hash"] is None
    assert r["training_hash"] is None
    base = {k: 1.0 for k in ("command_s", "cli_command_time_s", "first_call_s")}
    runs = [
        {**base, "seed": i, "env_steps_per_s": 1.0, "to_5mm_s": t5, "to_5mm_env_steps": t5,
         "to_1mm_s": t1, "to_1mm_env_steps": t1}
        for i, (t5, t1) in enumerate(((3.0, None), (5.0, 8.0), (None, None)))
    ]  # fmt: skip
    m = median_record(runs, "cold")
    assert m["to_5mm_s"] == 5.0 and m["reached_5mm"] == 2  # unreached: later than any
    assert m["to_1mm_s"] is None and m["reached_1mm"] == 1  # the median seed never got there


def test_tta_reads_a_several_seed_run_as_one_record(tmp_path):
    """`--seeds N`'s folder: the seeds' rates summed (one program), times as medians."""
    from mara_mjx.bench.tta import read_seeds

    for seed, (rate, hit_s) in {3: (100.0, 4.0), 4: (300.0, None), 5: (200.0, 6.0)}.items():
        folder = tmp_path / f"seed_{seed}"
        folder.mkdir()
        rows = ["update,env_steps,time_s,steps_per_s,det_error_mm", "1,10,2.0,1.0,9.0"]
        rows += [f"2,20,3.0,{rate},{rate / 100}"]
        (folder / "progress.csv").write_text("\n".join(rows) + "\n")
        hits = {"5mm": {"time_s": hit_s, "env_steps": 20}} if hit_s else {}
        summary = {"time_to_accuracy": hits, "command_time_s": 9.0 + seed}
        (folder / "summary.json").write_text(json.dumps(summary))
    r = read_seeds(tmp_path, 3, 3, offset=0.5)
    assert r["num_seeds"] == 3 and r["env_steps"] == 60
    assert r["env_steps_per_s"] == 600.0  # 100 + 300 + 200
    assert r["to_5mm_s"] == 6.5 and r["reached_5mm"] == 2  # median of 4.5, 6.5, never
    assert r["to_1mm_s"] is None and r["final_det_error_mm"] == 2.0
    assert (r["first_call_s"], r["cli_command_time_s"]) == (2.5, 14.5)
    assert r["state_hash"] is None and len(r["per_seed"]) == 3


def test_compile_clock_counts_overlapping_spans_once():
    with CompileClock() as clock:
        t0 = clock.start
        for start, end in ((1, 3), (2, 4), (6, 7), (-5, 0.5)):  # nested, apart, before
            clock._listen("/jax/core/compile/backend_compile_duration", t0 + start, t0 + end)
        clock._listen("/jax/other/event", t0 + 8, t0 + 9)
        assert clock.compile_s(t0 + 10) == pytest.approx(3 + 1 + 0.5)
        assert clock.compile_s(t0 + 2.5) == pytest.approx(0.5 + 1.5)


def test_run_summary_subtracts_compile():
    run = Run("test", "MARA")
    times = [(1.0, 1.0), (5.0, 4.0), (7.0, 5.0), (8.0, 5.0)]  # (t_s, compile so far)
    errors = [None, 8.0, 3.0, 0.5]
    for i, ((t, c), e) in enumerate(zip(times, errors, strict=True)):
        run.curve.append({"t_s": t, "compile_s": c, "env_steps": 100 * i, "settled_mm": e})
        run.snapshots.append(None)
    out = run.summary()
    assert [p["t_run_s"] for p in out["curve"]] == [0.0, 1.0, 2.0, 3.0]
    assert out["compile_s"] == 5.0 and out["compile_after_first_call_s"] == 1.0
    assert out["env_steps_per_s"] == pytest.approx(200 / 2.0)  # from the end of call 1
    assert out["first_call_overhead_s"] == pytest.approx(1.0 - 100 / 100)
    assert out["settled_to_5mm_s"] == 2.0 and out["settled_to_5mm_wall_s"] == 7.0
    assert out["settled_to_1mm_env_steps"] == 300 and out["best_settled_mm"] == 0.5


def test_bad_input_as_a_user_sees_it():
    """The command line itself: exit status 2 and the problem named, no traceback."""
    proc = subprocess.run(
        _cli("env", "--tasks", "NoSuchTask"),
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, "JAX_PLATFORMS": "cpu"},
    )
    assert proc.returncode == 2 and "unknown task" in proc.stderr
    assert "Traceback" not in proc.stderr


@pytest.mark.parametrize(
    "args, message",
    [
        (["nostudy"], "invalid choice"),
        (["env", "--tasks", "NoSuchTask"], "unknown task"),
        (["env", "--out", "/proc/forbidden"], "not writable"),
        (["brax", "--num_envs", "6"], "divisible by num_minibatches"),
        (["train", "--num_minibatches", "7"], "does not divide"),
        (["scaling", "--envs_per_device", "0"], "must be an int >= 1"),
        (["scaling", "--device_counts", "64"], "not available"),
        (["tta", "--tasks", "MARA", "MARAOrient"], "tta trains one task"),
        (["tta", "--train_args", "--seed 3"], "the study sets --seed itself"),
        (["tta", "--train_args=--no_such_flag"], "unrecognized arguments: --no_such_flag"),
        (["tta", "--train_args", "--num_envs 0"], "num_envs must be an int >= 1"),
    ],
)
def test_bad_input_gives_clear_error(args, message, capsys, compiled):
    """In-process (the same `main` as the command above): exit 2 before any compile."""
    from mara_mjx.cli.benchmark import main

    with pytest.raises(SystemExit) as stop:
        main(args)
    assert stop.value.code == 2
    assert message in capsys.readouterr().err
    assert not compiled


RESOLVE_AT_ONCE = """
import os, sys, traceback
from mara_mjx.bench import runner

parser = runner.build_parser("")
children = []
for _ in range(4):  # forked once the modules are imported: the four start together
    pid = os.fork()
    if pid == 0:
        status = 0
        try:
            for _ in range(300):
                runner.resolve(parser, ["env", "--quick", "--out", sys.argv[1]])
        except BaseException:
            traceback.print_exc()
            status = 1
        sys.stdout.flush()
        os._exit(status)
    children.append(pid)
statuses = [os.waitstatus_to_exitcode(os.waitpid(pid, 0)[1]) for pid in children]
print("statuses", statuses)
sys.exit(1 if any(statuses) else 0)
"""


def test_studies_sharing_an_output_folder_all_start(tmp_path):
    """Several studies check one --out folder at once (as `runs` above starts them): each
    check uses a file of its own (mara_mjx.runtime.files), so none removes another's (CI saw
    that). Four processes, each resolving a study's config 300 times: forked from one
    that imported the runner (four imports cost 4 x 3 s of CPU), so they start together."""
    proc = _popen([sys.executable, "-c", RESOLVE_AT_ONCE, str(tmp_path)])
    output = proc.communicate(timeout=120)[0]
    assert proc.returncode == 0, output[-3000:]
    assert "statuses [0, 0, 0, 0]" in output, output[-3000:]
    assert list(tmp_path.iterdir()) == []  # every check removed its file


def test_every_study_parses_without_brax(monkeypatch):
    """brax is optional: the benchmark CLI's parser (which builds every study's default
    config) must not need it, so that `python -m mara_mjx.benchmark tta` runs without it."""
    import importlib.util

    from mara_mjx.bench import runner

    real = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util, "find_spec", lambda name, *a: None if name == "brax" else real(name, *a)
    )
    monkeypatch.setitem(sys.modules, "brax", None)  # import brax -> ImportError
    parser = runner.build_parser("test")
    assert parser.parse_args(["tta", "--quick"]) is not None


def test_the_parser_starts_no_jax_backend():
    """`runner.configure` sets XLA_FLAGS and the GPU memory preallocation before the
    backend starts; the parser (every study's default config) must not start it first
    (the tta study's train commands failed on a GPU when it did)."""
    code = (
        "from jax._src import xla_bridge as xb\n"
        "from mara_mjx.bench import runner\n"
        "runner.build_parser('x')\n"
        "print('started' if xb._backends else 'not started')\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip().splitlines()[-1] == "not started"


def test_a_study_s_recorded_command_runs_the_same_study():
    """The command a study records (JSON, markdown) quotes a recipe with flags: split as a
    shell splits it, it gives back the argv the study ran with (joined with plain spaces,
    `--recipes cli --randomize` hands --randomize to the study, not to the recipe)."""
    import shlex

    from mara_mjx.bench.runner import command_line

    argv = ["robustness", "--recipes", "orient_first_noisy_starts --plan_steps 16", "--seeds", "2"]
    line = command_line(argv)
    assert shlex.split(line) == ["python", "-m", "mara_mjx.benchmark", *argv]
    assert "'orient_first_noisy_starts --plan_steps 16'" in line
    assert command_line(["env", "--quick"]) == "python -m mara_mjx.benchmark env --quick"
