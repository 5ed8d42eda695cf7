"""The phase table of benchmarks/warm_start_profile.py's JSON files (one column per file).

python benchmarks/warm_start_table.py OUT1.json [OUT2.json ...]
"""

import json
import statistics as st
import sys


def phases(path):
    d = json.load(open(path))
    m = dict(d["marks"])
    ev = {}
    for n, s, e, th, _ in d["events"]:
        if th == "MainThread":
            ev.setdefault(n, []).append((s, e))

    def first(n):
        return ev[n][0]

    P = {}
    P["interpreter start (to wrapper line 1)"] = m["wrapper_first_line"]
    P["import jax"] = first("import jax")[1] - first("import jax")[0]
    P["import mujoco"] = first("import mujoco")[1] - first("import mujoco")[0]
    P["import mara_mjx.cli.train (rest)"] = (
        first("import mara_mjx.cli.train (rest)")[1] - first("import mara_mjx.cli.train (rest)")[0]
    )
    P["argument parsing (build_parser+parse)"] = (
        first("cli.build_parser")[1] - m["main_start"] + (m["main_start"] - m["imports_done"])
    )
    mk = first("mara_mjx.make (env build)")
    P["configure_jax, resolve, backend init"] = mk[0] - first("cli.build_parser")[1]
    P["env build (mara_mjx.make)"] = mk[1] - mk[0]
    tr = first("warmup.traced")
    P["make_train, run folder, config.json, RunLogger"] = tr[0] - mk[1]
    es = [x for x in ev.get("eval_shape", []) if tr[0] <= x[0] <= tr[1]]
    P["traced: eval_shape(init) = trace of init"] = es[0][1] - es[0][0]
    er, ep = first("exported_run"), first("exported_probe")
    P["traced: trace-cache load run+probe (key material, read, jax.export.deserialize)"] = (
        er[1] - er[0]
    ) + (ep[1] - ep[0])
    P["traced: other"] = (
        (tr[1] - tr[0])
        - P["traced: eval_shape(init) = trace of init"]
        - P["traced: trace-cache load run+probe (key material, read, jax.export.deserialize)"]
    )
    ic = first("trainer.init call")
    tl = first("cli.train_loop")
    P["gap traced->init (warmup.start, waits)"] = ic[0] - tr[1]
    P["trainer.init call (lower+exe load+run)"] = ic[1] - ic[0]
    P["init -> train_loop (waits, print)"] = tl[0] - ic[1]
    rc = ev["trainer.run call"]
    pc = ev.get("trainer.probe call", [])
    P["first trainer.run call"] = rc[0][1] - rc[0][0]
    P["first probe call"] = pc[0][1] - pc[0][0] if pc else 0
    sc = first("save_checkpoint")
    P["rest of loop (metrics, CSV, 2nd call, ...)"] = sc[0] - (pc[0][1] if pc else rc[0][1])
    P["checkpoint save"] = sc[1] - sc[0]
    fi = first("cli.finish")
    P["finish (summary.json, eval, plots)"] = fi[1] - fi[0]
    P["loop end -> main end (close, gather, barrier, unlock)"] = (
        m["main_end"] - tl[1] - (fi[1] - fi[0])
    )
    P["TOTAL to main end"] = m["main_end"]
    try:
        P["exit (atexit + interpreter teardown) to atexit-last"] = (
            float(open(path + ".exit").read()) - m["main_end"]
        )
    except Exception:
        pass
    return P, d


runs = sys.argv[1:]
res = [phases(r)[0] for r in runs]
keys = list(res[0])
print(
    f"{'phase':75s} "
    + " ".join(f"{r.split('/')[-2] + '/' + r.split('/')[-1][:5]:>11s}" for r in runs)
    + "   median(warm)"
)
for k in keys:
    vals = [x.get(k, float("nan")) for x in res]
    warm = [v for r, v in zip(runs, vals, strict=False) if "warm" in r]
    print(
        f"{k:75s} "
        + " ".join(f"{v:11.3f}" for v in vals)
        + (f"   {st.median(warm):8.3f}" if warm else "")
    )
