"""Prototype: the whole deterministic policy step of mara_mjx's IK-residual presets exported
with jax2onnx, checked against the JAX function it was traced from.

    /tmp/j2o_venv/bin/python /tmp/onnx_proto/proto.py            # all presets, both inputs
    /tmp/j2o_venv/bin/python /tmp/onnx_proto/proto.py --only MARACollisionOrient
    ... --slow        # without j2o_fastpatch (jax2onnx's own O(N^2) output binding)
    ... --tree DIR    # a mara_mjx source tree (default ./work: HEAD 5a44557 + PATCH.diff)

Runs in /tmp/j2o_venv (jax 0.10.2, jax2onnx 0.17.1, onnx 1.23.2, onnxruntime 1.32.0;
the project's own env keeps onnx 1.19.1 / onnxruntime 1.23.2, and each exported file is
also run there, by subprocess). Nothing is trained: a random-init ActorCritic of the
preset's shape, its output head scaled up so the learnt correction is large (as a trained
one is), random observation statistics. Writes out/<name>.onnx, out/results.json.
"""

from __future__ import annotations

import argparse
import importlib.metadata
import json
import os
import subprocess
import sys
import time
from pathlib import Path

os.environ.setdefault("JAX_PLATFORMS", "cpu")
HERE = Path(__file__).resolve().parent
parser = argparse.ArgumentParser()
parser.add_argument("--tree", default=str(HERE / "work"))
parser.add_argument("--only", default="")
parser.add_argument("--slow", action="store_true")
parser.add_argument("--no-latency", action="store_true")
args = parser.parse_args()
sys.path.insert(0, args.tree)
sys.path.insert(0, str(HERE))

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import onnx  # noqa: E402
import onnxruntime as ort  # noqa: E402

if not args.slow:
    import j2o_fastpatch  # noqa: F401,E402
import jax2onnx  # noqa: E402
from jax2onnx import to_onnx  # noqa: E402

import mara_mjx  # noqa: E402
import mara_mjx.envs.task_space as ts  # noqa: E402
from mara_mjx.envs.geometry import quat_conj, quat_mul  # noqa: E402
from mara_mjx.ppo.config import for_env  # noqa: E402
from mara_mjx.ppo.presets import PRESETS, default_preset  # noqa: E402
from mara_mjx.ppo.networks import RunningStats, make_network  # noqa: E402
from mara_mjx.ppo.policy import Policy  # noqa: E402

OUT = HERE / "out"
OUT.mkdir(exist_ok=True)
TOL = 1e-4
FULL_CHECK: dict[str, str] = {}
OFFSETS = (-1e-3, -1e-5, 0.0, 1e-5, 1e-3)  # relative offsets from each zone boundary
SYSTEM_PYTHON = "/root/.pyenv/versions/3.11.7/bin/python"  # onnx 1.19.1, onnxruntime 1.23.2


# ----------------------------------------------------------------------------- policy
def make_random_policy(env_name: str, seed: int = 0):
    """(env, config, Policy, deployed step obs -> clipped joint targets) of the CLI's
    default preset for env_name, random init."""
    env = mara_mjx.make(env_name)
    config = for_env(PRESETS[default_preset(env_name)], env)
    network = make_network(config, 6)
    size = env.observation_size
    obs0 = jnp.zeros((size,))
    params = network.init(jax.random.key(seed), obs0, obs0)
    # the init head has gain 0.01: scale it so the learnt correction is O(0.1-1) rad
    head = params["params"]["actor"]["Dense_2"]
    head["kernel"] = head["kernel"] * 30.0
    head["bias"] = jnp.asarray(np.random.default_rng(seed).normal(0, 0.05, 6), jnp.float32)
    stats = None
    if config.normalize_obs:
        rng = np.random.default_rng(seed + 1)
        stats = RunningStats(
            mean=jnp.asarray(rng.normal(0, 0.1, size), jnp.float32),
            var=jnp.asarray(rng.uniform(0.05, 2.0, size), jnp.float32),
            count=jnp.ones(()),
        )
    policy = Policy(params=params, obs_stats=stats, config=config, action_size=6)
    lower = np.asarray(env.joint_lower, np.float32)
    upper = np.asarray(env.joint_upper, np.float32)

    def step(obs: jax.Array) -> jax.Array:
        """obs (B, obs_size) -> joint targets (B, 6) rad, clipped to the joint limits."""
        return jnp.clip(policy(obs), lower, upper)

    return env, config, policy, step


def robot_inputs(step, orientation: bool):
    """The deployed step from what a robot node has: q (B, 6) rad, qdot (B, 6) rad/s,
    target_pos (B, 3) m, target_quat (B, 4) (w, x, y, z): the observation (e, quat_err, v)
    is computed in the graph from the nominal chain's forward kinematics, as
    envs/mara.py's _observe does from the arm's pose."""
    chain = ts.nominal_chain()

    def observe(q, qdot, target_pos, target_quat):
        tcp_pos, tcp_quat = chain.tcp(q)
        jac = chain.jacobian(q)
        parts = [q, tcp_pos - target_pos]
        if orientation:
            parts.append(quat_mul(tcp_quat, quat_conj(target_quat)))
        parts.append(jac[:3] @ qdot)
        return jnp.concatenate(parts)

    obs_of = jnp.vectorize(observe, signature="(6),(6),(3),(4)->(n)")

    def robot_step(q, qdot, target_pos, target_quat):
        return step(obs_of(q, qdot, target_pos, target_quat))

    return robot_step, obs_of


# ------------------------------------------------------------------------ observations
def unit(rng, n, d):
    x = rng.normal(size=(n, d))
    return x / np.linalg.norm(x, axis=1, keepdims=True)


def quat_angle(axis, angle):
    return np.concatenate([np.cos(angle / 2)[:, None], np.sin(angle / 2)[:, None] * axis], 1)


def obs_from(q, e, quat, v, orientation):
    parts = [q, e] + ([quat] if orientation else []) + [v]
    return np.concatenate(parts, 1).astype(np.float32)


def random_obs(rng, n, lower, upper, orientation):
    q = rng.uniform(lower, upper, (n, 6))
    e = unit(rng, n, 3) * rng.choice([0.003, 0.02, 0.08, 0.3], (n, 1)) * rng.uniform(0.5, 1.5, (n, 1))
    quat = unit(rng, n, 4)
    small = rng.random(n) < 0.5  # half near the target orientation
    quat[small] = quat_angle(unit(rng, small.sum(), 3), rng.uniform(0, 0.4, small.sum()))
    quat *= rng.choice([-1.0, 1.0], (n, 1))
    v = rng.normal(0, 0.1, (n, 3))
    return obs_from(q, e, quat, v, orientation)


def boundary_families(rng, lower, upper, config, n=32):
    """name -> (offset -> obs (n, size)): observations at each zone boundary of the
    deployed rules, moved by each relative offset in OFFSETS."""
    orientation = config.quat_index >= 0
    fam: dict[str, dict[float, np.ndarray]] = {}
    q = rng.uniform(0.9 * lower, 0.9 * upper, (n, 6))
    v = rng.normal(0, 0.1, (n, 3))
    dirs = unit(rng, n, 3)
    axes = unit(rng, n, 3)

    def add(name, build):
        fam[name] = {d: build(d) for d in OFFSETS}

    if orientation:
        if config.ik_orient_first:
            dist = rng.uniform(0.005, 0.1, (n, 1))
            add("orient_first aligned (angle = 0.02 rad)", lambda d: obs_from(
                q, dirs * dist, quat_angle(axes, np.full(n, ts.ORIENT_FIRST_ALIGNED * (1 + d))), v, True))
            add("orient_first near/guard (|e| = 0.06 m)", lambda d: obs_from(
                q, dirs * ts.ORIENT_FIRST_NEAR * (1 + d),
                quat_angle(axes, rng.uniform(0, 0.5, n)), v, True))
            ang = rng.uniform(0.03, 0.7, n)
            floor = np.maximum(ts.ORIENT_FIRST_STANDOFF * np.maximum(ang - ts.MAX_ROTATION_STEP, 0), ts.ORIENT_FIRST_HOLD)
            add("orient_first standoff (|e| = standoff)", lambda d: obs_from(
                q, dirs * (floor * (1 + d))[:, None], quat_angle(axes, ang), v, True))
            add("orient_first move cap (|e| = standoff + 0.05)", lambda d: obs_from(
                q, dirs * ((floor + ts.MAX_POSITION_STEP) * (1 + d))[:, None], quat_angle(axes, ang), v, True))
            # the flange's long way round: goal = q5 - phi for a twist phi about its axis
            chain = ts.nominal_chain()
            jac = np.asarray(jax.vmap(chain.jacobian)(jnp.asarray(q, jnp.float32)))
            flange = jac[:, 3:, 5] / np.linalg.norm(jac[:, 3:, 5], axis=1, keepdims=True)
            lo6, hi6 = ts.last_joint_range()
            for label, edge, side in (("upper", hi6, 1), ("lower", lo6, -1)):
                qq = q.copy()
                qq[:, 5] = edge - side * rng.uniform(0.05, 0.2, n)
                def build(d, qq=qq, edge=edge):
                    phi = qq[:, 5] - edge * (1 + d)
                    return obs_from(qq, dirs * rng.uniform(0.0, 0.3, (n, 1)), quat_angle(flange, phi), v, True)
                add(f"wrap goal at the {label} limit", build)
            edge2 = lo6 + 2 * np.pi  # the long way's end at the other limit
            qq = q.copy()
            qq[:, 5] = hi6 - rng.uniform(0.05, 0.2, n)
            add("wrap: long way ends at the other limit", lambda d: obs_from(
                qq, dirs * 0.1, quat_angle(flange, qq[:, 5] - edge2 * (1 + d)), v, True))
        else:
            add("wrap near (|e| = 0.02 m)", lambda d: obs_from(
                q, dirs * ts.WRAP_NEAR * (1 + d), quat_angle(axes, rng.uniform(0, 3.0, n)), v, True))
        add("rotation step cap (angle = 0.25 rad)", lambda d: obs_from(
            q, dirs * 0.03, quat_angle(axes, np.full(n, ts.MAX_ROTATION_STEP * (1 + d))), v, True))
        add("rotation_vector small branch (|v| = 1e-6)", lambda d: obs_from(
            q, dirs * 0.03, quat_angle(axes, np.full(n, 2e-6 * (1 + d))), v, True))
        def w_flip(d):
            quat = np.concatenate([np.full((n, 1), d), unit(rng, n, 3)], 1)
            return obs_from(q, dirs * 0.05, quat / np.linalg.norm(quat, axis=1, keepdims=True), v, True)
        add("quaternion sign (w = offset, angle ~ pi)", w_flip)
    if config.ik_finish > 0:
        add("finish zone / guard (|e| = ik_finish)", lambda d: obs_from(
            q, dirs * config.ik_finish * (1 + d), None, v, False))
        add("finish aim (|e| = 1.2 cm)", lambda d: obs_from(
            q, dirs * ts.FINISH_WITHIN * ts.FINISH_HOLD * (1 + d), None, v, False))
    if config.ik_gate > 0:
        add("gate scale (|e| = ik_gate)", lambda d: obs_from(
            q, dirs * config.ik_gate * (1 + d), unit(rng, n, 4) if orientation else None, v, orientation))
    add("target reached (|e| = offset m)", lambda d: obs_from(
        q, dirs * abs(d), quat_angle(axes, np.full(n, abs(d))) if orientation else None, v, orientation))
    return fam


# --------------------------------------------------------------------------- checking
def session(path, threads=0):
    so = ort.SessionOptions()
    so.log_severity_level = 3
    if threads:
        so.intra_op_num_threads = threads
    return ort.InferenceSession(str(path), so, providers=["CPUExecutionProvider"])


def graph_stats(model):
    from collections import Counter

    ops, sub = Counter(), 0

    def walk(g, top):
        nonlocal sub
        for node in g.node:
            ops[node.op_type] += 1
            if not top:
                sub += 1
            for a in node.attribute:
                if a.type == onnx.AttributeProto.GRAPH:
                    walk(a.g, False)

    walk(model.graph, True)
    return {
        "nodes_total": sum(ops.values()),
        "nodes_in_subgraphs": sub,
        "initializers": len(model.graph.initializer),
        "ops": dict(ops.most_common()),
        "opset": [(o.domain, o.version) for o in model.opset_import],
        "ir_version": model.ir_version,
    }


def latency(sess, feeds, reps):
    sess.run(None, feeds)
    times = []
    for _ in range(reps):
        t = time.perf_counter()
        sess.run(None, feeds)
        times.append(time.perf_counter() - t)
    return float(np.median(times) * 1e3), float(np.percentile(times, 90) * 1e3)


def export(fn, specs, name, input_names):
    t = time.perf_counter()
    model = to_onnx(fn, specs, model_name=name, opset=17, input_names=input_names,
                    output_names=["joint_targets"])
    seconds = time.perf_counter() - t
    path = OUT / f"{name}.onnx"
    onnx.save(model, str(path))
    try:
        onnx.checker.check_model(str(path), full_check=True)
        full_check = "ok"
    except Exception as ex:  # noqa: BLE001 - recorded, the file may still run
        full_check = f"{type(ex).__name__}: {str(ex)[:300]}"
        print("onnx.checker full_check:", full_check)
    FULL_CHECK[name] = full_check
    return path, model, seconds


def check_in_system_ort(path, feeds, expected):
    """Run the file in the project's environment (onnxruntime 1.23.2): max |diff|."""
    npz = OUT / f"{path.stem}_check.npz"
    np.savez(npz, expected=expected, **feeds)
    code = (
        "import numpy as np, onnxruntime as ort, sys;"
        f"d=np.load('{npz}');so=ort.SessionOptions();so.log_severity_level=3;"
        f"s=ort.InferenceSession('{path}',so,providers=['CPUExecutionProvider']);"
        "f={i.name:d[i.name] for i in s.get_inputs()};"
        "print(ort.__version__, float(np.abs(s.run(None,f)[0]-d['expected']).max()))"
    )
    out = subprocess.run([SYSTEM_PYTHON, "-c", code], capture_output=True, text=True, env={
        "PATH": "/usr/bin:/bin", "HOME": os.environ.get("HOME", "/root")})
    if out.returncode:
        return {"error": out.stderr.strip().splitlines()[-1]}
    version, err = out.stdout.split()
    return {"onnxruntime": version, "max_abs_err": float(err)}


def run_obs_variant(env_name, results):
    env, config, policy, step = make_random_policy(env_name)
    size, orientation = env.observation_size, config.quat_index >= 0
    lower, upper = np.asarray(env.joint_lower), np.asarray(env.joint_upper)
    name = f"{env_name}_obs"
    print(f"\n== {name}: preset {default_preset(env_name)}: ik_prior={config.ik_prior!r} "
          f"gate={config.ik_gate} wrap={config.ik_wrap} gate_wrap={config.ik_gate_wrap} "
          f"orient_first={config.ik_orient_first} finish={config.ik_finish}", flush=True)
    path, model, seconds = export(step, [("B", size)], name, ["obs"])
    stats = graph_stats(model)
    print(f"exported in {seconds:.1f} s: {stats['nodes_total']} nodes "
          f"({stats['nodes_in_subgraphs']} in loop bodies), {path.stat().st_size / 1e3:.0f} kB")
    sess = session(path)
    jitted = jax.jit(step)
    rng = np.random.default_rng(1)
    obs = random_obs(rng, 4000, lower, upper, orientation)
    got = sess.run(None, {"obs": obs})[0]
    want = np.asarray(jitted(obs))
    with jax.disable_jit():  # the same JAX function compiled differently: the float32 floor
        eager = np.asarray(step(jnp.asarray(obs)))
    err = np.abs(got - want).max(1)
    floor = np.abs(eager - want).max(1)
    moved = np.abs(want - obs[:, :6]).max(1)
    entry = {
        "env": env_name, "preset": default_preset(env_name), "input": "obs",
        "export_seconds": round(seconds, 1), "file_bytes": path.stat().st_size, **stats, "full_check": FULL_CHECK[name],
        "random": {"n": len(obs), "max_abs_err": float(err.max()),
                   "n_over_tol": int((err > TOL).sum()), "p99_err": float(np.quantile(err, 0.99)),
                   "jax_eager_vs_jit_max": float(floor.max()),
                   "jax_eager_vs_jit_n_over_tol": int((floor > TOL).sum()),
                   "max_step_rad": float(moved.max())},
        "boundaries": {},
    }
    print(f"random obs: ORT vs jit max {err.max():.2e} ({(err > TOL).sum()} > {TOL}); "
          f"JAX eager vs jit max {floor.max():.2e} ({(floor > TOL).sum()} > {TOL})")
    for fam, sets in boundary_families(rng, lower, upper, config).items():
        row = {}
        for d, o in sets.items():
            g = sess.run(None, {"obs": o})[0]
            w = np.asarray(jitted(o))
            with jax.disable_jit():
                ee = np.asarray(step(jnp.asarray(o)))
            quat = jnp.asarray(o[:, 9:13]) if orientation else None
            flag = np.asarray(ts.pose_step_wrapping(
                jnp.asarray(o[:, :6]), jnp.asarray(o[:, 6:9]), quat, config.ik_wrap,
                config.ik_orient_first)[1]) if config.ik_prior else np.zeros(len(o), bool)
            row[f"{d:+g}"] = {"max_abs_err": float(np.abs(g - w).max()),
                             "jax_floor": float(np.abs(ee - w).max()),
                             "gate_closed_frac": float(flag.mean())}
        entry["boundaries"][fam] = row
        print(f"  {fam:48s} " + "  ".join(
            f"{k}: {v['max_abs_err']:.1e}/{v['jax_floor']:.1e}/{v['gate_closed_frac']:.2f}"
            for k, v in row.items()))
    entry["system_ort"] = check_in_system_ort(path, {"obs": obs}, want)
    print("project env onnxruntime:", entry["system_ort"])
    if not args.no_latency:
        for threads in (1, 2):
            s = session(path, threads)
            one = latency(s, {"obs": obs[:1]}, 300)
            many = latency(s, {"obs": obs[:1000]}, 30)
            entry[f"ort_latency_ms_threads{threads}"] = {"batch1_median_p90": one, "batch1000_median_p90": many}
        jit_one = jitted(obs[:1]).block_until_ready()
        t = []
        for _ in range(300):
            t0 = time.perf_counter(); jitted(obs[:1]).block_until_ready(); t.append(time.perf_counter() - t0)
        jitted(obs[:1000]).block_until_ready()
        t2 = []
        for _ in range(30):
            t0 = time.perf_counter(); jitted(obs[:1000]).block_until_ready(); t2.append(time.perf_counter() - t0)
        entry["jax_jit_latency_ms"] = {"batch1_median": float(np.median(t) * 1e3), "batch1000_median": float(np.median(t2) * 1e3)}
        print("latency ms (median, p90):", {k: v for k, v in entry.items() if "latency" in k})
        del jit_one
    results.append(entry)
    return env, config, step


def run_robot_variant(env_name, env, config, step, results):
    orientation = config.quat_index >= 0
    robot_step, obs_of = robot_inputs(step, orientation)
    name = f"{env_name}_robot"
    print(f"\n== {name}: inputs q, qdot, target_pos, target_quat", flush=True)
    specs = [("B", 6), ("B", 6), ("B", 3), ("B", 4)]
    names = ["q", "qdot", "target_pos", "target_quat"]
    path, model, seconds = export(robot_step, specs, name, names)
    stats = graph_stats(model)
    print(f"exported in {seconds:.1f} s: {stats['nodes_total']} nodes, "
          f"{path.stat().st_size / 1e3:.0f} kB")
    # the graph's observation is the env's: reset states of the env, its own obs
    keys = jax.random.split(jax.random.key(3), 64)
    states = jax.jit(jax.vmap(env.reset))(keys)
    q = np.asarray(states.q, np.float32)
    qdot = np.random.default_rng(4).normal(0, 0.3, (64, 6)).astype(np.float32)
    tp = np.asarray(states.params.target_pos, np.float32)
    tq = np.asarray(states.params.target_quat, np.float32)
    env_obs = np.asarray(states.obs)
    graph_obs = np.asarray(jax.jit(obs_of)(q, np.zeros_like(qdot), tp, tq))
    obs_err = float(np.abs(env_obs - graph_obs).max())
    # random robot inputs, including targets across the workspace
    rng = np.random.default_rng(5)
    n = 4000
    lower, upper = np.asarray(env.joint_lower), np.asarray(env.joint_upper)
    qr = rng.uniform(lower, upper, (n, 6)).astype(np.float32)
    qdr = rng.normal(0, 0.3, (n, 6)).astype(np.float32)
    chain = ts.nominal_chain()
    qt = np.clip(qr + rng.normal(0, 1, (n, 1)) * rng.choice([0.003, 0.05, 0.5], (n, 1)) * rng.normal(size=(n, 6)), lower, upper)
    tpr, tqr = (np.asarray(x, np.float32) for x in jax.vmap(chain.tcp)(jnp.asarray(qt, jnp.float32)))
    tqr = tqr * rng.choice([-1.0, 1.0], (n, 1)).astype(np.float32)
    feeds = {"q": qr, "qdot": qdr, "target_pos": tpr, "target_quat": tqr}
    got = session(path).run(None, feeds)[0]
    want = np.asarray(jax.jit(robot_step)(qr, qdr, tpr, tqr))
    err = np.abs(got - want).max(1)
    entry = {"env": env_name, "input": "q, qdot, target_pos, target_quat",
             "export_seconds": round(seconds, 1), "file_bytes": path.stat().st_size, **stats, "full_check": FULL_CHECK[name],
             "graph_obs_vs_env_obs_max": obs_err,
             "random": {"n": n, "max_abs_err": float(err.max()), "n_over_tol": int((err > TOL).sum())}}
    entry["system_ort"] = check_in_system_ort(path, feeds, want)
    print(f"graph obs vs env obs (reset states): {obs_err:.2e}; random: ORT vs jit max "
          f"{err.max():.2e} ({(err > TOL).sum()} > {TOL}); project ORT: {entry['system_ort']}")
    if not args.no_latency:
        s = session(path, 1)
        entry["ort_latency_ms_threads1"] = {
            "batch1_median_p90": latency(s, {k: v[:1] for k, v in feeds.items()}, 300),
            "batch1000_median_p90": latency(s, {k: v[:1000] for k, v in feeds.items()}, 30)}
        print("latency ms:", entry["ort_latency_ms_threads1"])
    results.append(entry)


def main():
    envs = ["MARACollisionOrient", "MARACollisionOrientRandomTarget", "MARA", "MARARandomTarget"]
    robot = {"MARACollisionOrient", "MARACollisionOrientRandomTarget", "MARA"}
    if args.only:
        envs = args.only.split(",")
    print(f"jax {jax.__version__}, jax2onnx {importlib.metadata.version('jax2onnx')}, "
          f"onnx {onnx.__version__}, onnxruntime {ort.__version__}, tree {args.tree}, "
          f"fastpatch {not args.slow}")
    results = []
    for name in envs:
        env, config, step = run_obs_variant(name, results)
        if name in robot:
            run_robot_variant(name, env, config, step, results)
        results_path = OUT / (f"results_{args.only.replace(',', '_')}.json" if args.only else "results.json")
        results_path.write_text(json.dumps(results, indent=1))
    print("\nwrote", results_path)


if __name__ == "__main__":
    main()
