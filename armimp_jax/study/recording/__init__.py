"""A lab's recordings: reading them, the Welch and model routes, pooled postures, calibration
files, their figures and reports, and a lab's day for a movement."""
