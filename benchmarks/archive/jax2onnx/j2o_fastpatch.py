"""Optional speed patch for jax2onnx 0.17.1's converter (prototype only; opt in with
J2O_FASTPATCH=1). Its `output_binding._value_is_graph_connected` scans every graph input,
initializer and node for each equation's outputs: O(N^2) in graph size (~100 s for the
4,300-node IK policy on this CPU). This asks the value itself (its producer node's graph,
or its name among the graph's inputs and initializers); the ORT check catches any error."""
from jax2onnx.converter import output_binding as ob

_orig = ob._value_is_graph_connected


def _connected(ctx, value):
    graph = getattr(ctx.builder, "graph", None)
    if graph is None:
        return _orig(ctx, value)
    producer = value.producer()
    if producer is not None and producer.graph is graph:
        return True
    if value.name and value.name in graph.initializers:
        return True
    return any(ob._value_matches_reference(x, value) for x in ctx.builder.inputs) or (
        producer is None and _orig(ctx, value)
    )


ob._value_is_graph_connected = _connected
