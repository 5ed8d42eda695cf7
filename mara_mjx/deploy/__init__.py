"""Policies outside JAX: the numpy IK finish and the ONNX graph of an exported policy."""
