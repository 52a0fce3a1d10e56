"""An ONNX model run by ONNX Runtime on one CPU thread, its inputs and outputs checked at load.

The detector plug-ins (:mod:`lastmile.perception.lidar_detector`,
:mod:`lastmile.perception.camera_detector`) each declare their I/O contract as :class:`TensorSpec`
rows; :class:`OnnxModel` refuses a model whose input or output names, element types or fixed
dimensions differ from it, with one line naming what was expected and what the file holds. A
dimension the contract leaves free (``None``) may be anything in the model; a dimension the model
leaves symbolic (a name, as exported with dynamic axes) passes any fixed one in the contract and is
checked again when the model runs.

ONNX Runtime is an optional dependency (``pip install lastmile[detector]``): nothing imports it until
a model is loaded.
"""

from __future__ import annotations

import importlib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from lastmile.core.errors import ConfigError, MessageError
from lastmile.core.object_class import ObjectClass

_ORT_TYPES = {
    np.dtype(np.float32): "tensor(float)",
    np.dtype(np.int64): "tensor(int64)",
    np.dtype(np.uint8): "tensor(uint8)",
}


@dataclass(frozen=True, slots=True, kw_only=True)
class TensorSpec:
    """One named input or output of a model contract.

    Attributes:
        name: the tensor's name in the graph.
        dtype: its element type (float32, int64 or uint8).
        shape: its dimensions; ``None`` where any size is allowed (a count of detections).
    """

    name: str
    dtype: np.dtype[Any]
    shape: tuple[int | None, ...]

    def describe(self) -> str:
        dims = ", ".join("?" if d is None else str(d) for d in self.shape)
        return f"{self.name!r} {self.dtype} ({dims})"


def _describe_model_tensor(arg: Any) -> str:
    dims = ", ".join(str(d) if isinstance(d, int) else "?" for d in arg.shape)
    return f"{arg.name!r} {arg.type} ({dims})"


def _load_runtime() -> Any:
    try:
        return importlib.import_module("onnxruntime")
    except ImportError:
        raise ConfigError(
            "ONNX detector: expected the onnxruntime package (pip install 'lastmile[detector]'), "
            "got none installed"
        ) from None


class OnnxModel:
    """An ONNX model on ONNX Runtime's CPU provider, one thread, sequential, deterministic compute.

    Args:
        path: the ``.onnx`` file.
        inputs, outputs: the contract: the model must have exactly these inputs and at least these
            outputs (extra outputs are not computed).
        what: how errors name the model's role (``"LiDAR detector"``).

    Raises:
        ConfigError: onnxruntime missing, no such file, not a loadable ONNX model, or a contract
            mismatch, each in one line.
    """

    def __init__(
        self, path: Path, inputs: Sequence[TensorSpec], outputs: Sequence[TensorSpec], what: str
    ) -> None:
        self.path = Path(path)
        self.what = what
        self.inputs = tuple(inputs)
        self.outputs = tuple(outputs)
        if not self.path.is_file():
            raise ConfigError(f"{what} model {self.path}: expected an ONNX model file, got no such file")
        ort = _load_runtime()
        options = ort.SessionOptions()
        # One thread and sequential execution: the stack shares its core with the rest of the loop,
        # and a run must repeat bit for bit from its seed (a thread pool may reorder float sums).
        options.intra_op_num_threads = 1
        options.inter_op_num_threads = 1
        options.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
        options.use_deterministic_compute = True
        options.log_severity_level = 3
        try:
            self._session = ort.InferenceSession(
                str(self.path), sess_options=options, providers=["CPUExecutionProvider"]
            )
        except Exception as exc:  # ONNX Runtime raises its own pybind error types
            first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            raise ConfigError(
                f"{what} model {self.path}: expected a valid ONNX model, got one ONNX Runtime cannot load "
                f"({first})"
            ) from None
        self._check(self._session.get_inputs(), self.inputs, "input", exact=True)
        self._check(self._session.get_outputs(), self.outputs, "output", exact=False)
        self._output_names = [s.name for s in self.outputs]

    def _check(self, found: Sequence[Any], specs: Sequence[TensorSpec], kind: str, exact: bool) -> None:
        by_name = {a.name: a for a in found}
        for spec in specs:
            arg = by_name.get(spec.name)
            if arg is None:
                got = ", ".join(_describe_model_tensor(a) for a in found) or "none"
                raise ConfigError(
                    f"{self.what} model {self.path}: expected {kind} {spec.describe()}, got {kind}s {got}"
                )
            if not self._matches(arg, spec):
                raise ConfigError(
                    f"{self.what} model {self.path}: expected {kind} {spec.describe()}, "
                    f"got {_describe_model_tensor(arg)}"
                )
        if exact and len(found) != len(specs):
            extra = [a.name for a in found if a.name not in {s.name for s in specs}]
            raise ConfigError(
                f"{self.what} model {self.path}: expected {kind}s "
                f"{[s.name for s in specs]} only, got also {extra}"
            )

    @staticmethod
    def _matches(arg: Any, spec: TensorSpec) -> bool:
        if arg.type != _ORT_TYPES[np.dtype(spec.dtype)]:
            return False
        shape = arg.shape
        if shape is None or len(shape) != len(spec.shape):
            return False
        return all(
            want is None or not isinstance(have, int) or have == want
            for have, want in zip(shape, spec.shape, strict=True)
        )

    def run(self, feeds: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
        """Run the model on ``feeds`` (one array per contract input); the contract's outputs by name.

        Raises:
            MessageError: an output whose element type or shape breaks the contract (a model with
                symbolic dimensions can only be checked here).
        """
        values = self._session.run(self._output_names, dict(feeds))
        out: dict[str, np.ndarray] = {}
        for spec, value in zip(self.outputs, values, strict=True):
            arr = np.asarray(value)
            ok_shape = arr.ndim == len(spec.shape) and all(
                want is None or have == want for have, want in zip(arr.shape, spec.shape, strict=True)
            )
            if arr.dtype != spec.dtype or not ok_shape:
                raise MessageError(
                    f"{self.what} model {self.path}: expected output {spec.describe()}, "
                    f"got {arr.dtype} {arr.shape}"
                )
            out[spec.name] = arr
        return out


def check_detections(where: str, boxes: np.ndarray, scores: np.ndarray, class_id: np.ndarray) -> None:
    """A detector's outputs, one row per detection: as many boxes, scores and classes, finite boxes
    and scores, scores in [0, 1] and :class:`ObjectClass` ids.

    Raises:
        MessageError: naming the model (``where``) and the first breach.
    """
    if not (len(boxes) == len(scores) == len(class_id)):
        raise MessageError(
            f"{where}: expected as many boxes, scores and classes, got {len(boxes)}, {len(scores)}, "
            f"{len(class_id)}"
        )
    if not (np.isfinite(boxes).all() and np.isfinite(scores).all()):
        raise MessageError(f"{where}: expected finite boxes and scores, got NaN or inf")
    if ((scores < 0) | (scores > 1)).any():
        raise MessageError(f"{where}: expected scores in [0, 1], got {scores.min():.3g}..{scores.max():.3g}")
    ids = [int(c) for c in ObjectClass]
    known = np.isin(class_id, ids)
    if not known.all():
        raise MessageError(f"{where}: expected ObjectClass ids {ids}, got {int(class_id[~known][0])}")
