"""A learned camera 2D detector as a plug-in: an ONNX model on one camera image.

Contract (checked when the model loads, :class:`~lastmile.perception.onnx_model.OnnxModel`):

- input ``image``: float32 ``(1, 3, H, W)``, RGB in [0, 1], H and W the camera's ``height_px`` and
  ``width_px`` (no resizing or letterboxing here: export the model at the camera's resolution);
- output ``boxes``: float32 ``(1, K, 4)``, u_min, v_min, u_max, v_max in pixels;
- output ``scores``: float32 ``(1, K)``, in [0, 1];
- output ``classes``: int64 ``(1, K)``, :class:`~lastmile.core.object_class.ObjectClass` ids.

Boxes under ``min_score`` are dropped and the rest clipped to the image; the result is the
:class:`~lastmile.core.sensor_frames.CameraDetections` that late fusion
(:func:`lastmile.perception.late_fusion.fuse_objects`) reads, the same message the simulator's
model-free detector sends. The simulator renders no images, so the running stack does not use this
detector (see the README); it is for real camera frames.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lastmile.core.camera_model import PinholeCamera
from lastmile.core.errors import ConfigError, MessageError
from lastmile.core.sensor_frames import CameraDetections
from lastmile.core.stamp import Stamp
from lastmile.perception.onnx_model import OnnxModel, TensorSpec, check_detections


@dataclass(frozen=True, slots=True, kw_only=True)
class CameraDetectorConfig:
    """Attributes:
    model: path of the ``.onnx`` file.
    min_score: boxes below this score are dropped (late fusion applies its own
        ``min_camera_score`` too).
    """

    model: str
    min_score: float = 0.1

    def __post_init__(self) -> None:
        if not self.model:
            raise ConfigError("CameraDetectorConfig.model: expected the path of an .onnx file, got ''")
        if not (math.isfinite(self.min_score) and 0.0 <= self.min_score <= 1.0):
            raise ConfigError(f"CameraDetectorConfig.min_score: expected 0..1, got {self.min_score}")


def camera_detector_contract(
    height_px: int, width_px: int
) -> tuple[tuple[TensorSpec, ...], tuple[TensorSpec, ...]]:
    """The model's inputs and outputs for an image of ``height_px`` x ``width_px``."""
    f32, i64 = np.dtype(np.float32), np.dtype(np.int64)
    inputs = (TensorSpec(name="image", dtype=f32, shape=(1, 3, height_px, width_px)),)
    outputs = (
        TensorSpec(name="boxes", dtype=f32, shape=(1, None, 4)),
        TensorSpec(name="scores", dtype=f32, shape=(1, None)),
        TensorSpec(name="classes", dtype=i64, shape=(1, None)),
    )
    return inputs, outputs


class OnnxCameraDetector:
    """Runs the configured model on one camera's images; see the module docstring for the contract.

    Raises:
        ConfigError: at construction, when the model cannot be loaded or breaks the contract.
    """

    def __init__(self, config: CameraDetectorConfig, camera: PinholeCamera) -> None:
        self.config = config
        self.camera = camera
        inputs, outputs = camera_detector_contract(camera.height_px, camera.width_px)
        self.model = OnnxModel(Path(config.model), inputs, outputs, f"camera {camera.camera_id!r} detector")

    def detect(self, image_rgb: np.ndarray, stamp: Stamp) -> CameraDetections:
        """Boxes in an (H, W, 3) RGB image (uint8 0..255, or float 0..1) captured at ``stamp``.

        Raises:
            MessageError: an image of another size or type, or a model output that breaks the
                contract (counts that disagree, non-finite or inverted boxes, scores outside [0, 1],
                unknown classes).
        """
        cam = self.camera
        img = np.asarray(image_rgb)
        if img.shape != (cam.height_px, cam.width_px, 3):
            raise MessageError(
                f"camera {cam.camera_id!r} detector: expected an (H, W, 3) = "
                f"({cam.height_px}, {cam.width_px}, 3) RGB image, got {img.shape}"
            )
        if img.dtype == np.uint8:
            x = img.astype(np.float32) / 255.0
        elif img.dtype.kind == "f" and np.isfinite(img).all() and img.min() >= 0 and img.max() <= 1:
            x = img.astype(np.float32)
        else:
            raise MessageError(
                f"camera {cam.camera_id!r} detector: expected a uint8 image or floats in [0, 1], "
                f"got {img.dtype}"
            )
        out = self.model.run({"image": np.ascontiguousarray(x.transpose(2, 0, 1)[None])})
        boxes = out["boxes"][0].astype(np.float64)
        scores = out["scores"][0].astype(np.float64)
        cls = out["classes"][0]
        self._check(boxes, scores, cls)
        keep = scores >= self.config.min_score
        boxes = boxes[keep]
        boxes[:, [0, 2]] = np.clip(boxes[:, [0, 2]], 0.0, cam.width_px)
        boxes[:, [1, 3]] = np.clip(boxes[:, [1, 3]], 0.0, cam.height_px)
        table = np.column_stack([boxes, cls[keep].astype(np.float64), scores[keep]])
        return CameraDetections(stamp=stamp, camera_id=cam.camera_id, boxes=table.astype(np.float32))

    def _check(self, boxes: np.ndarray, scores: np.ndarray, cls: np.ndarray) -> None:
        where = f"camera {self.camera.camera_id!r} detector model {self.model.path}"
        check_detections(where, boxes, scores, cls)
        if ((boxes[:, 2] < boxes[:, 0]) | (boxes[:, 3] < boxes[:, 1])).any():
            raise MessageError(f"{where}: expected u_min <= u_max and v_min <= v_max, got an inverted box")
