"""Independent rig truth for benchmarking ``diagnose``: damper, driver, sensors and cases.

Written apart from the fitting code: nothing here imports ``identification``,
``core.extended``, ``core.driver`` or ``core.damper``. ``rig`` (damper and driver ODEs and the
rig programmes), ``sensors`` (realistic measurement chain), ``cases`` (ready-made records),
``vehicle`` (a quarter car with hidden corner effects and its IMU/stroke sensors, for
``diagnose-vehicle``; it imports no core plant, damper or driver either).
"""
