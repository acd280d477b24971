"""The imaging chain: PSFs, Bayer mosaic and demosaic, shot and read noise, quantisation.

Planned content (issue 5): ``degrade`` works on any linear float image and imports nothing
from ``orbit`` or ``raytrace``.
"""
