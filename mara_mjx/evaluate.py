"""`python -m mara_mjx.evaluate`: runs mara_mjx/cli/evaluate.py (its docstring is the manual)."""

if __name__ == "__main__":
    import runpy

    runpy.run_module("mara_mjx.cli.evaluate", run_name="__main__", alter_sys=True)
