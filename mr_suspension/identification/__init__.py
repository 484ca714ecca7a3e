"""Damper diagnosis: from rig data to the missing physics, the extended model and its gain.

Modules: ``data`` (CSV/.mat/rosbag2 loaders, units, checks), ``engine`` (effect catalogue,
current dynamics, separable fits with blocked cross-validation),
``diagnose`` (selection and verdict), ``synthetic`` (truth generator and rig programme),
``report`` (JSON/Markdown/plots), ``model_io`` (fitted model files), ``cli``.
"""
