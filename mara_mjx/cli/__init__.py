"""The command-line programs (`python -m mara_mjx.train`, `evaluate`, `play`, `export`,
`benchmark`; the root modules of those names start them) and their shared plumbing.
"""
