"""Helpers for struct-of-arrays message fields: read-only arrays with checked shape and finiteness."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from lastmile.core.errors import MessageError


def frozen_array(values: npt.ArrayLike, dtype: npt.DTypeLike, columns: int | None, what: str) -> np.ndarray:
    """A read-only copy of ``values`` as ``dtype`` with shape (N, columns) (or (N,) when None).

    An array of ``dtype`` that owns its data and is already read-only is taken as it is, not copied:
    its producer has handed it over (a simulated LiDAR sweep's megabyte of points), and a copy would
    be just as read-only.

    Raises:
        MessageError: naming ``what`` if the shape is wrong or a value is NaN or infinite.
    """
    arr: np.ndarray
    if (
        isinstance(values, np.ndarray)
        and values.base is None
        and not values.flags.writeable
        and values.dtype == np.dtype(dtype)
    ):
        arr = values  # handed over
    else:
        arr = np.array(values, dtype=dtype, copy=True)
    if columns is None:
        if arr.ndim != 1:
            raise MessageError(f"{what}: expected a 1-D array, got shape {arr.shape}")
    else:
        if arr.size == 0:
            arr = arr.reshape(0, columns)
        if arr.ndim != 2 or arr.shape[1] != columns:
            raise MessageError(f"{what}: expected shape (N, {columns}), got {arr.shape}")
    # The smallest and largest values are finite exactly when all are (a NaN propagates through
    # both reductions): two SIMD reductions instead of a boolean array of every element.
    if arr.dtype.kind == "f" and arr.size and not (np.isfinite(arr.min()) and np.isfinite(arr.max())):
        raise MessageError(f"{what}: expected finite values, got NaN or inf")
    arr.setflags(write=False)
    return arr


def check_frozen_array(values: npt.ArrayLike, dtype: npt.DTypeLike, columns: int | None, what: str) -> None:
    """Raises exactly when :func:`frozen_array` would, without its copy when ``values`` already is an
    array of ``dtype`` (a message's own field: ``validate()`` runs on every frame, several times).

    Raises:
        MessageError: naming ``what`` if the shape is wrong or a value is NaN or infinite.
    """
    if not (isinstance(values, np.ndarray) and values.dtype == np.dtype(dtype)):
        frozen_array(values, dtype, columns, what)
        return
    arr = values
    if columns is None:
        if arr.ndim != 1:
            raise MessageError(f"{what}: expected a 1-D array, got shape {arr.shape}")
    elif arr.size != 0 and (arr.ndim != 2 or arr.shape[1] != columns):
        raise MessageError(f"{what}: expected shape (N, {columns}), got {arr.shape}")
    if arr.dtype.kind == "f" and arr.size and not (np.isfinite(arr.min()) and np.isfinite(arr.max())):
        raise MessageError(f"{what}: expected finite values, got NaN or inf")
