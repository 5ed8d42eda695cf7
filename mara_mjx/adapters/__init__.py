"""Everyone else's interfaces to the MARA envs: gymnasium (`mara_mjx/<task>-v0`, single and
vector) and brax (`make_brax_env`, for brax's own trainers).
"""
