"""Independent rig truth for benchmarking ``diagnose``: damper, driver, sensors and cases.

Written apart from the fitting code: nothing here imports ``identification``,
``core.extended``, ``core.driver`` or ``core.damper``. ``rig`` (damper and driver ODEs and the
rig programmes), ``sensors`` (realistic measurement chain), ``cases`` (ready-made records).
"""
