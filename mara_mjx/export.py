"""`python -m mara_mjx.export`: runs mara_mjx/cli/export.py (its docstring is the manual)."""

if __name__ == "__main__":
    import runpy

    runpy.run_module("mara_mjx.cli.export", run_name="__main__", alter_sys=True)
