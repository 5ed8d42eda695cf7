"""`python -m mara_mjx.plots`: runs mara_mjx/viz/plots.py (its docstring is the manual)."""

if __name__ == "__main__":
    import runpy

    runpy.run_module("mara_mjx.viz.plots", run_name="__main__", alter_sys=True)
