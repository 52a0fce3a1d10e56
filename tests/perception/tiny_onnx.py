"""Tiny ONNX detectors the tests build themselves with onnx's helper API (nothing is downloaded).

- :func:`bev_peak_detector`: a CenterPoint-like head without weights: the BEV raster's first channel
  (plus a tiny constant ramp that breaks ties between equal cells) is max-pooled; every cell equal to
  its pooled value and above a threshold is a peak, and each peak becomes one fixed-size box at its
  cell centre, scored by the channel's value (capped at 1), of one class.
- :func:`red_blob_detector`: the bounding box of the pixels whose red channel exceeds a threshold,
  one box (or none when no pixel does), of one class, score 0.9.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

from lastmile.perception.bev_raster import BevGrid


def _const(name: str, value: np.ndarray) -> onnx.NodeProto:
    return helper.make_node("Constant", [], [name], value=numpy_helper.from_array(value, name=name))


def _save(graph: onnx.GraphProto, path: Path) -> Path:
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    onnx.checker.check_model(model)
    onnx.save(model, str(path))
    return path


def bev_peak_detector(
    path: Path,
    grid: BevGrid,
    *,
    threshold: float,
    class_id: int,
    box_lwh_m: tuple[float, float, float],
    window_cells: int = 5,
    bev_name: str = "bev",
    scores_dtype: int = TensorProto.FLOAT,
) -> Path:
    """Write the BEV peak detector for ``grid`` to ``path`` (see the module docstring)."""
    _, C, H, W = grid.shape
    ramp = (np.arange(H * W, dtype=np.float32).reshape(1, 1, H, W) / (H * W)) * 1e-4
    length, width, height = box_lwh_m
    half = window_cells // 2
    nodes = [
        _const("ch_start", np.array([0], np.int64)),
        _const("ch_end", np.array([1], np.int64)),
        _const("ch_axis", np.array([1], np.int64)),
        helper.make_node("Slice", [bev_name, "ch_start", "ch_end", "ch_axis"], ["heat0"]),
        _const("ramp", ramp),
        helper.make_node("Add", ["heat0", "ramp"], ["heat"]),
        helper.make_node(
            "MaxPool",
            ["heat"],
            ["pooled"],
            kernel_shape=[window_cells, window_cells],
            pads=[half, half, half, half],
            strides=[1, 1],
        ),
        helper.make_node("Equal", ["heat", "pooled"], ["is_max"]),
        _const("thr", np.array(threshold, np.float32)),
        helper.make_node("Greater", ["heat0", "thr"], ["above"]),
        helper.make_node("And", ["is_max", "above"], ["peak"]),
        helper.make_node("NonZero", ["peak"], ["idx"]),  # (4, K): n, c, row, col
        helper.make_node("Transpose", ["idx"], ["idx_t"], perm=[1, 0]),  # (K, 4)
        helper.make_node("GatherND", ["heat0", "idx_t"], ["value"]),  # (K,)
        _const("one", np.array(1.0, np.float32)),
        helper.make_node("Min", ["value", "one"], ["score_k"]),
        _const("rc_idx", np.array([2, 3], np.int64)),
        helper.make_node("Gather", ["idx_t", "rc_idx"], ["rc"], axis=1),  # (K, 2)
        helper.make_node("Cast", ["rc"], ["rc_f"], to=TensorProto.FLOAT),
        _const("cell", np.array([grid.cell_m, grid.cell_m], np.float32)),
        _const(
            "origin",
            np.array([grid.x_min_m + grid.cell_m / 2, grid.y_min_m + grid.cell_m / 2], np.float32),
        ),
        helper.make_node("Mul", ["rc_f", "cell"], ["rc_m"]),
        helper.make_node("Add", ["rc_m", "origin"], ["xy"]),  # (K, 2)
        _const("col0_s", np.array([0], np.int64)),
        _const("col0_e", np.array([1], np.int64)),
        helper.make_node("Slice", ["xy", "col0_s", "col0_e", "ch_axis"], ["x_col"]),  # (K, 1)
        _const("zero", np.array(0.0, np.float32)),
        helper.make_node("Mul", ["x_col", "zero"], ["zeros_k1"]),
        _const("rest", np.array([[height / 2, length, width, height, 0.0]], np.float32)),
        helper.make_node("Add", ["zeros_k1", "rest"], ["rest_k"]),  # (K, 5)
        helper.make_node("Concat", ["xy", "rest_k"], ["boxes_k"], axis=1),  # (K, 7)
        _const("axis0", np.array([0], np.int64)),
        helper.make_node("Unsqueeze", ["boxes_k", "axis0"], ["boxes"]),
        helper.make_node("Unsqueeze", ["score_k", "axis0"], ["scores_f"]),
        helper.make_node("Cast", ["scores_f"], ["scores"], to=scores_dtype),
        helper.make_node("Cast", ["score_k"], ["score_i"], to=TensorProto.INT64),
        _const("cls", np.array(class_id, np.int64)),
        helper.make_node("Mul", ["score_i", "zero_i"], ["zeros_i"]),
        _const("zero_i", np.array(0, np.int64)),
        helper.make_node("Add", ["zeros_i", "cls"], ["cls_k"]),
        helper.make_node("Unsqueeze", ["cls_k", "axis0"], ["classes"]),
    ]
    # Constants must come before their users in a valid graph.
    nodes = [n for n in nodes if n.op_type == "Constant"] + [n for n in nodes if n.op_type != "Constant"]
    graph = helper.make_graph(
        nodes,
        "bev_peak_detector",
        [helper.make_tensor_value_info(bev_name, TensorProto.FLOAT, [1, C, H, W])],
        [
            helper.make_tensor_value_info("boxes", TensorProto.FLOAT, [1, "K", 7]),
            helper.make_tensor_value_info("scores", scores_dtype, [1, "K"]),
            helper.make_tensor_value_info("classes", TensorProto.INT64, [1, "K"]),
        ],
    )
    return _save(graph, path)


def red_blob_detector(path: Path, height_px: int, width_px: int, *, threshold: float, class_id: int) -> Path:
    """Write the red-blob detector for ``height_px`` x ``width_px`` images to ``path``."""
    H, W = height_px, width_px
    v_grid = np.broadcast_to(np.arange(H, dtype=np.float32)[:, None], (H, W)).reshape(1, 1, H, W)
    u_grid = np.broadcast_to(np.arange(W, dtype=np.float32)[None, :], (H, W)).reshape(1, 1, H, W)
    nodes = [
        _const("c0", np.array([0], np.int64)),
        _const("c1", np.array([1], np.int64)),
        helper.make_node("Slice", ["image", "c0", "c1", "c1"], ["red"]),
        _const("thr", np.array(threshold, np.float32)),
        helper.make_node("Greater", ["red", "thr"], ["mask"]),
        _const("u", np.ascontiguousarray(u_grid)),
        _const("v", np.ascontiguousarray(v_grid)),
        _const("big", np.array(1e6, np.float32)),
        _const("neg", np.array(-1e6, np.float32)),
        _const("onef", np.array(1.0, np.float32)),
        helper.make_node("Where", ["mask", "u", "big"], ["u_in"]),
        helper.make_node("Where", ["mask", "v", "big"], ["v_in"]),
        helper.make_node("Add", ["u", "onef"], ["u1"]),
        helper.make_node("Add", ["v", "onef"], ["v1"]),
        helper.make_node("Where", ["mask", "u1", "neg"], ["u_out"]),
        helper.make_node("Where", ["mask", "v1", "neg"], ["v_out"]),
        helper.make_node("ReduceMin", ["u_in"], ["u_min"], keepdims=0),
        helper.make_node("ReduceMin", ["v_in"], ["v_min"], keepdims=0),
        helper.make_node("ReduceMax", ["u_out"], ["u_max"], keepdims=0),
        helper.make_node("ReduceMax", ["v_out"], ["v_max"], keepdims=0),
        _const("shape1", np.array([1], np.int64)),
        helper.make_node("Reshape", ["u_min", "shape1"], ["a"]),
        helper.make_node("Reshape", ["v_min", "shape1"], ["b"]),
        helper.make_node("Reshape", ["u_max", "shape1"], ["c"]),
        helper.make_node("Reshape", ["v_max", "shape1"], ["d"]),
        helper.make_node("Concat", ["a", "b", "c", "d"], ["box4"], axis=0),
        _const("shape14", np.array([1, 4], np.int64)),
        helper.make_node("Reshape", ["box4", "shape14"], ["box_1"]),  # (1, 4)
        helper.make_node("Cast", ["mask"], ["mask_f"], to=TensorProto.FLOAT),
        helper.make_node("ReduceMax", ["mask_f"], ["any"], keepdims=0),
        helper.make_node("Reshape", ["any", "shape1"], ["any1"]),
        helper.make_node("NonZero", ["any1"], ["keep"]),  # (1, K), K = 0 or 1
        helper.make_node("Squeeze", ["keep", "c0"], ["keep_k"]),
        helper.make_node("Gather", ["box_1", "keep_k"], ["boxes_k"], axis=0),  # (K, 4)
        helper.make_node("Unsqueeze", ["boxes_k", "c0"], ["boxes"]),
        _const("score_c", np.array([0.9], np.float32)),
        helper.make_node("Gather", ["score_c", "keep_k"], ["score_k"], axis=0),
        helper.make_node("Unsqueeze", ["score_k", "c0"], ["scores"]),
        _const("cls_c", np.array([class_id], np.int64)),
        helper.make_node("Gather", ["cls_c", "keep_k"], ["cls_k"], axis=0),
        helper.make_node("Unsqueeze", ["cls_k", "c0"], ["classes"]),
    ]
    nodes = [n for n in nodes if n.op_type == "Constant"] + [n for n in nodes if n.op_type != "Constant"]
    graph = helper.make_graph(
        nodes,
        "red_blob_detector",
        [helper.make_tensor_value_info("image", TensorProto.FLOAT, [1, 3, H, W])],
        [
            helper.make_tensor_value_info("boxes", TensorProto.FLOAT, [1, "K", 4]),
            helper.make_tensor_value_info("scores", TensorProto.FLOAT, [1, "K"]),
            helper.make_tensor_value_info("classes", TensorProto.INT64, [1, "K"]),
        ],
    )
    return _save(graph, path)
