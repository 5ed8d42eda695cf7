"""The benchmark studies behind `python -m mara_mjx.benchmark STUDY`, one module each.

    env.py      batched env step throughput (BatchedEnv.step in a lax.scan)
    peers.py    C MuJoCo (all CPU cores) vs MJX, same physics (cpeer.py: the C pool)
    ppo.py      train (our PPO end to end) and brax (brax's PPO against ours)
    limit.py    one env step against the device's roofline
    scaling.py  throughput against the number of devices
    runner.py   what they share: BenchConfig, Study, flags from each study's config,
                output (<study>.json / .md / .png), provenance

Each study module imports the runner and nothing of the others except `env` (the timed
rollout it shares); the runner imports the studies only by name (`STUDIES`), on use.
"""
