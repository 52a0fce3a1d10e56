"""lastmile.perception.

The compiled kernels (``*_kernel.py``, Numba ``cache=True``) cache in the user's cache folder, set here,
before any of them imports Numba.
"""

from lastmile.core.user_cache import use_user_cache_for_numba

use_user_cache_for_numba()
