"""`python -m mara_mjx.benchmark`: runs mara_mjx/cli/benchmark.py (its docstring is the manual)."""

if __name__ == "__main__":
    import runpy

    runpy.run_module("mara_mjx.cli.benchmark", run_name="__main__", alter_sys=True)
