"""Private numba kernels: NumPy in, NumPy out. They import only numpy, numba and math.

Public, validating wrappers live in the modules above (``o3d_terrain.grid``,
``o3d_terrain.spline``, ...). Kernels are compiled with ``cache=True``.
"""
