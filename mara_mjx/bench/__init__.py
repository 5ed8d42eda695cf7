"""The benchmark studies behind `python -m mara_mjx.benchmark STUDY`, one module each
(some with helpers of their own).

    env.py          batched env step throughput (BatchedEnv.step in a lax.scan)
    peers.py        C MuJoCo (all CPU cores) vs MJX, same physics (cpeer.py: the C pool)
    ppo.py          train (our PPO end to end) and brax (brax's PPO against ours;
                    ppo_runs.py: the timed runs and their scorer, brax_peer.py: brax's side)
    limit.py        one env step against the device's roofline
    scaling.py      throughput against the number of devices
    tta.py          time to accuracy from command start, cold and warm, the PPO's speed
                    (also with --seeds N); tta_report.py: its table, notes and figure
    robustness.py   training recipes over many seeds, each judged as its task is judged
                    (robustness_judge.py: the judgements; robustness_report.py: the
                    statistics, table and figure)
    train_command.py  the user's train command as a fresh process (tta, robustness)
    runner.py       what they share: BenchConfig, Study, flags from each study's config,
                    output (<study>.json / .md / .png), provenance

Each study module imports the runner and nothing of the others except `env` (the timed
rollout it shares), `limit` (tta's roofline part) and its own helpers; the runner imports
the studies only by name (`STUDIES`), on use.
"""
