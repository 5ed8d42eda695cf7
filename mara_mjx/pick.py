"""`python -m mara_mjx.pick`: runs mara_mjx/cli/pick.py (its docstring is the manual)."""

if __name__ == "__main__":
    import runpy

    runpy.run_module("mara_mjx.cli.pick", run_name="__main__", alter_sys=True)
