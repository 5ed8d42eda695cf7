"""Policies outside JAX: an exported policy in numpy (with its IK finish) and as ONNX
graphs, the robot-side runner, an exported file in the evaluation loop."""
