"""The physics, bottom floor: the arm, the robot, joint friction, sensors, controllers, the
perturbation, the clock (``timing``: the control period and sample rate) and the coupled
plant's equations of motion. Nothing here integrates in time
(that is ``_solver``) or knows about estimation, batches, files or the paper."""
