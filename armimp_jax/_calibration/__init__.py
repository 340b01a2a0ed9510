"""The robot calibrated alone (inverse-dynamics least squares through its friction) and the
force transducer against known loads: ``calibrate_robot``, ``calibrate_force``."""
