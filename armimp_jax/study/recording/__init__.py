"""A lab's recordings: reading them, the Welch and model routes, pooled postures, calibration
files, their figures and reports, and a lab's day for a movement."""

from .. import _folder_getattr

__getattr__ = _folder_getattr(__name__, "recording")  # 3.2.0's module study.recording is this folder's recording now
