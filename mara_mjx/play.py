"""`python -m mara_mjx.play`: runs mara_mjx/cli/play.py (its docstring is the manual)."""

if __name__ == "__main__":
    import runpy

    runpy.run_module("mara_mjx.cli.play", run_name="__main__", alter_sys=True)
