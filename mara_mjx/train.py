"""`python -m mara_mjx.train`: runs mara_mjx/cli/train.py (its docstring is the manual)."""

if __name__ == "__main__":
    import runpy

    runpy.run_module("mara_mjx.cli.train", run_name="__main__", alter_sys=True)
