"""Runtime helpers shared by the passes: worker threads in order, per-thread scratch
buffers, handing freed memory back to the system, numba's cache of the kernels.

May import: the standard library, numpy, OpenCV, numba. Must not import any other
pipestitch package: every layer may use it, so it sits below all of them.
"""
