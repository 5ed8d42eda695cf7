"""Which JAX constructs jax2onnx 0.17.1 lowers (batch dim symbolic 'B'), each checked in
onnxruntime against JAX. Small functions shaped like the policy's pieces."""
import os
os.environ.setdefault("JAX_PLATFORMS", "cpu")
import sys; sys.path.insert(0, "/tmp/onnx_proto")
import j2o_fastpatch  # noqa
import jax, jax.numpy as jnp, numpy as np, onnxruntime as ort
from jax2onnx import to_onnx

rng = np.random.default_rng(0)
A = rng.normal(size=(8, 6, 6)).astype(np.float32)
SPD = (A @ A.transpose(0, 2, 1) + 0.1 * np.eye(6)).astype(np.float32)
X = rng.normal(size=(8, 6)).astype(np.float32)

@jax.custom_jvp
def softclip(x):
    return jnp.tanh(x)
softclip.defjvp(lambda p, t: (softclip(p[0]), t[0] * (1 - jnp.tanh(p[0]) ** 2)))

def spd_solve_cho(a, b):
    c = jnp.linalg.cholesky(a)
    return jax.scipy.linalg.cho_solve((c, True), b)

cases = {
    "jnp.linalg.solve (batched 6x6, LU)": ((SPD, X), lambda a, b: jnp.linalg.solve(a, b[..., None])[..., 0]),
    "jnp.linalg.solve under vmap": ((SPD, X), jax.vmap(jnp.linalg.solve)),
    "cholesky + cho_solve under vmap": ((SPD, X), jax.vmap(spd_solve_cho)),
    "lax.cond, batched predicate under vmap": ((X,), jax.vmap(lambda x: jax.lax.cond(x[0] > 0, lambda y: y * 2, lambda y: -y, x))),
    "lax.cond, scalar predicate (top level)": ((X,), lambda x: jax.lax.cond(x[0, 0] > 0, lambda y: y * 2, lambda y: -y, x)),
    "lax.while_loop top level (carry)": ((X,), lambda x: jax.lax.while_loop(lambda c: c[0] < 5, lambda c: (c[0] + 1, c[1] * 0.5 + 1), (0, x))[1]),
    "lax.fori_loop under vmap": ((X,), jax.vmap(lambda x: jax.lax.fori_loop(0, 4, lambda i, c: c * 0.5 + 1, x))),
    "lax.fori_loop top level closing over input": ((X,), lambda x: jax.lax.fori_loop(0, 4, lambda i, c: c * 0.5 + x, jnp.zeros_like(x))),
    "custom_jvp function": ((X,), lambda x: softclip(x)),
    "jax.nn.relu (custom_jvp) + softplus": ((X,), lambda x: jax.nn.relu(x) + jax.nn.softplus(x)),
    "jnp.dot of 1-D under vmap": ((X, X), jax.vmap(lambda a, b: jnp.dot(a, b))),
    "gather x[argmax] under vmap": ((X,), jax.vmap(lambda x: jnp.stack([x, -x])[jnp.argmax(x[:2])])),
    "jnp.arctan2, where, norm under vmap": ((X, X), jax.vmap(lambda a, b: jnp.arctan2(a, b) * jnp.where(jnp.linalg.norm(a) < 1, 1.0, 2.0))),
    "lax.platform_dependent": ((X,), lambda x: jax.lax.platform_dependent(x, cpu=lambda y: y + 1, default=lambda y: y - 1)),
}
for name, (inputs, fn) in cases.items():
    specs = [("B",) + x.shape[1:] for x in inputs]
    try:
        model = to_onnx(fn, specs, opset=17)
        so = ort.SessionOptions(); so.log_severity_level = 3
        s = ort.InferenceSession(model.SerializeToString(), so, providers=["CPUExecutionProvider"])
        got = s.run(None, {i.name: x for i, x in zip(s.get_inputs(), inputs)})[0]
        want = np.asarray(jax.jit(fn)(*inputs))
        ops = sorted({n.op_type for n in model.graph.node})
        print(f"OK    {name}: max err {np.abs(got - want).max():.1e}; ops incl. {[o for o in ops if o in ('Loop','If','Scan','GatherND','Gather','Atan','Where')]}")
    except Exception as ex:
        print(f"FAIL  {name}: {type(ex).__name__}: {str(ex).splitlines()[0][:160]}")
