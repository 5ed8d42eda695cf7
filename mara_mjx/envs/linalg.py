"""Small dense linear algebra written out element by element (6 x 6 and smaller).

Two reasons not to call the library (`jnp.linalg.solve`, LAPACK's batched LU on a CPU):

* XLA fuses the written-out factorisation with its neighbours, where a library call is a
  kernel of its own (the real driver's step, envs/dynamics.py);
* on a CPU, jaxlib's batched LAPACK kernels split their batch over XLA's intra-op thread
  pool and block a pool thread until the parts are done: when as many of them run at once
  as the pool has threads (2 on a 2-core machine; XLA runs independent ops of a program
  concurrently), every thread waits for work that no thread is free to run, and the
  program never finishes (benchmarks/NOTES.md section 30: the train CLI's Orient default
  hung at its first update on this project's 2-core VM). The IK step's solve
  (envs/task_space.py) uses `spd_solve` on a CPU for that reason. Not covered: the
  real driver through MJX (`kinematics='mjx'` or `real_contacts='physical'`), whose
  `mjx.step` factorises with a batched LAPACK Cholesky on a CPU.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp


def spd_solve(a: jax.Array, b: jax.Array) -> jax.Array:
    """a^-1 b for a symmetric positive definite (..., n, n) a and (..., n) b: Cholesky written out
    element by element, so that XLA fuses it with the rest of the step (a library
    factorisation is a separate call per matrix; these are 6 x 6), and no LAPACK call."""
    n = a.shape[-1]
    low = [[None] * n for _ in range(n)]
    for j in range(n):
        diag = jnp.sqrt(a[..., j, j] - sum(low[j][k] * low[j][k] for k in range(j)))
        low[j][j] = diag
        for i in range(j + 1, n):
            low[i][j] = (a[..., i, j] - sum(low[i][k] * low[j][k] for k in range(j))) / diag
    y = []
    for i in range(n):
        y.append((b[..., i] - sum(low[i][k] * y[k] for k in range(i))) / low[i][i])
    x = [None] * n
    for i in reversed(range(n)):
        x[i] = (y[i] - sum(low[k][i] * x[k] for k in range(i + 1, n))) / low[i][i]
    return jnp.stack(x, axis=-1)
