"""The MDRL core: target-localization environments, observations, networks, PPO, baselines.

Usable alone (``drlaas train`` / ``drlaas eval`` on a laptop); imports nothing from the platform.
"""
