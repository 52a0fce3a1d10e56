"""lastmile.perception.

The compiled kernels (``*_kernel.py``, Numba ``cache=True``) take ``njit`` from :mod:`.jit_cache`, which
points Numba's cache at the user's cache folder before any kernel is decorated.
"""
