"""The exported deterministic policy as an ONNX graph (the optional `[onnx]` extra).

    python -m mara_mjx.export runs/MARA-.../ policy.onnx

    import onnxruntime as ort
    session = ort.InferenceSession("policy.onnx")
    action, = session.run(["action"], {"obs": obs[None].astype(np.float32)})   # (1, 6) rad

The graph is built node by node with `onnx.helper` from the weights `mara_mjx.export`
writes (no converter), and computes exactly what `NumpyPolicy` (and `make_policy`)
computes, in float32:

    input  obs             (N, obs_size) float32, the raw observation (env.observation_layout)
    x = obs, its quaternion block times the sign of its w      (canonical_quat, quat_index)
    x = clip((x - mean) / sqrt(var + 1e-8), -obs_clip, obs_clip)   (observation normaliser)
    x = x * visible                                             (hidden_obs set to 0)
    x = tanh(x @ W_i + b_i) ..., then x @ W_L + b_L             (the actor MLP)
    output action          (N, 6) rad: x (+ obs[:, :6] with relative_actions; before
                           that x = m tanh(x / m) with max_joint_step m > 0)
    output action_clipped  (N, 6) rad: action clipped to the joint limits, as the env does

The export metadata (observation layout, joint names, limits, units, source) is stored as
the model's `metadata_props` under the key "mara_mjx" (JSON). onnx is imported here only.
"""

from __future__ import annotations

import json
from typing import Any

import numpy as np

OPSET = 17
IR_VERSION = 8  # readable by every onnxruntime since 1.10


def build_model(policy: Any) -> Any:
    """The onnx.ModelProto of a `numpy_policy.NumpyPolicy`."""
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    meta = policy.meta
    if meta.get("ik_finish"):
        raise ValueError(
            "this policy keeps an IK finish (meta 'ik_finish', format mara_mjx.export/2), "
            "which the ONNX graph cannot run; export the checkpoint again with "
            "--drop_ik_finish for .onnx, or run the .npz in numpy"
        )
    obs_size, act_size = policy.observation_size, policy.action_size
    nodes: list[Any] = []
    inits: list[Any] = []

    def const(name: str, value: np.ndarray) -> str:
        inits.append(numpy_helper.from_array(np.asarray(value), name))
        return name

    def node(op: str, inputs: list[str], name: str, **attrs) -> str:
        nodes.append(helper.make_node(op, inputs, [name], name=name, **attrs))
        return name

    x = "obs"
    quat = int(meta.get("quat_index", -1))
    if quat >= 0:  # canonical sign: w >= 0 (w == 0 counts as positive, as in JAX)
        w = node(
            "Slice",
            [
                x,
                const("quat_w_start", np.array([quat], np.int64)),
                const("quat_w_end", np.array([quat + 1], np.int64)),
                const("quat_w_axis", np.array([1], np.int64)),
            ],
            "quat_w",
        )
        negative = node("Less", [w, const("zero", np.zeros((), np.float32))], "quat_negative")
        sign = node(
            "Where",
            [
                negative,
                const("minus_one", -np.ones((), np.float32)),
                const("one", np.ones((), np.float32)),
            ],
            "quat_sign",
        )  # (N, 1)
        block = np.zeros(obs_size, np.float32)
        block[quat : quat + 4] = 1.0
        outside = node("Sub", [const("one_vector", np.ones(obs_size, np.float32)),
                               const("quat_block", block)], "outside_quat")  # fmt: skip
        # factor = 1 outside the block, the sign inside: exactly +-1, so the product is exact
        factor = node("Add", [outside, node("Mul", [sign, "quat_block"], "signed_block")],
                      "quat_factor")  # fmt: skip
        x = node("Mul", [x, factor], "obs_canonical")
    if policy.obs_mean is not None:
        clip = float(meta["obs_clip"])
        # the same float32 arithmetic as mara_mjx.ppo.networks.normalize
        std = np.sqrt(policy.obs_var.astype(np.float32) + np.float32(meta["obs_var_eps"]))
        x = node("Sub", [x, const("obs_mean", policy.obs_mean.astype(np.float32))], "obs_centred")
        x = node("Div", [x, const("obs_std", std.astype(np.float32))], "obs_scaled")
        x = node(
            "Clip",
            [
                x,
                const("obs_clip_low", np.array(-clip, np.float32)),
                const("obs_clip_high", np.array(clip, np.float32)),
            ],
            "obs_normalised",
        )
    hidden = meta.get("hidden_obs", [])
    if hidden:
        visible = np.ones(obs_size, np.float32)
        visible[hidden] = 0.0
        x = node("Mul", [x, const("visible", visible)], "obs_visible")
    n = len(policy.kernels)
    for i, (kernel, bias) in enumerate(zip(policy.kernels, policy.biases, strict=True)):
        x = node("MatMul", [x, const(f"layer_{i}/kernel", kernel.astype(np.float32))], f"mm_{i}")
        x = node("Add", [x, const(f"layer_{i}/bias", bias.astype(np.float32))], f"dense_{i}")
        if i < n - 1:
            x = node("Tanh", [x], f"tanh_{i}")
    if meta.get("relative_actions", False):
        step = float(meta.get("max_joint_step", 0.0))
        if step > 0.0:  # m tanh(x / m) (PolicyConfig.max_joint_step)
            m = const("max_joint_step", np.array(step, np.float32))
            squashed = node("Tanh", [node("Div", [x, m], "step_div")], "step_tanh")
            x = node("Mul", [squashed, m], "step")
        q = node(
            "Slice",
            [
                "obs",
                const("q_start", np.array([0], np.int64)),
                const("q_end", np.array([act_size], np.int64)),
                const("q_axis", np.array([1], np.int64)),
            ],
            "q",
        )
        x = node("Add", [x, q], "relative")
    nodes.append(helper.make_node("Identity", [x], ["action"], name="action"))
    lower = const("joint_lower", policy.joint_lower.astype(np.float32))
    upper = const("joint_upper", policy.joint_upper.astype(np.float32))
    above = node("Max", ["action", lower], "above_lower")
    nodes.append(helper.make_node("Min", [above, upper], ["action_clipped"], name="clip_joints"))

    batch = "N"
    graph = helper.make_graph(
        nodes,
        f"mara_mjx_{policy.env_name}_policy",
        [helper.make_tensor_value_info("obs", TensorProto.FLOAT, [batch, obs_size])],
        [
            helper.make_tensor_value_info("action", TensorProto.FLOAT, [batch, act_size]),
            helper.make_tensor_value_info("action_clipped", TensorProto.FLOAT, [batch, act_size]),
        ],
        inits,
    )
    model = helper.make_model(
        graph,
        opset_imports=[helper.make_opsetid("", OPSET)],
        producer_name="mara_mjx",
        doc_string=f"Deterministic PPO policy for {policy.env_name}: obs (N, {obs_size}) -> "
        f"action (N, {act_size}) rad (absolute joint targets motor1..motor6).",
    )
    model.ir_version = IR_VERSION
    helper.set_model_props(model, {"mara_mjx": json.dumps(meta)})
    onnx.checker.check_model(model)
    return model


def save(policy: Any, file: Any) -> None:
    """Write the ONNX model of `policy` to `file` (a path or a binary file object)."""
    import onnx

    onnx.save(build_model(policy), file)
