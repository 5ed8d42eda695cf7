"""`python -m mara_mjx.select`: runs mara_mjx/cli/select.py (its docstring is the manual)."""

if __name__ == "__main__":
    import runpy

    runpy.run_module("mara_mjx.cli.select", run_name="__main__", alter_sys=True)
