"""KITTI tracking files: PointRCNN detections, ground-truth labels, and tracking results.

Formats (``../shared/data/README.md``):

- detections ``pointrcnn_<Class>/<seq>.txt``, comma separated:
  ``frame, type (1 Pedestrian, 2 Car, 3 Cyclist), x1, y1, x2, y2, score, h, w, l, x, y, z, rot_y, alpha``;
- labels ``<seq>.txt``, space separated:
  ``frame track_id type truncated occluded alpha x1 y1 x2 y2 h w l x y z rot_y`` (track_id -1: DontCare);
- results: the label format plus a ``score`` column.

3D boxes are KITTI camera boxes (x right, y down, z forward, y at the bottom); readers also give them
as z-up boxes (:mod:`lastmile.core.box3d`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lastmile.core.box3d import boxes_from_kitti_camera
from lastmile.core.errors import ConfigError, MessageError

CLASSES = ("Car", "Pedestrian", "Cyclist")
"""The three KITTI tracking classes that are scored."""

DETECTION_TYPE_IDS = {1: "Pedestrian", 2: "Car", 3: "Cyclist"}


@dataclass(frozen=True, slots=True, kw_only=True)
class KittiRows:
    """Rows of a KITTI detection, label or result file, struct-of-arrays.

    Attributes:
        frame: (N,) int64 frame index.
        track_id: (N,) int64; -1 for detections and DontCare.
        obj_type: (N,) str, KITTI type ("Car", "Van", "DontCare", ...).
        truncation: (N,) float64 (labels; 0 elsewhere).
        occlusion: (N,) int64 (labels; 0 elsewhere).
        alpha_rad: (N,) float64 observation angle.
        image_box: (N, 4) float64 ``x1 y1 x2 y2`` pixels.
        camera_box: (N, 7) float64 ``h w l x y z rot_y`` (KITTI camera frame).
        score: (N,) float64 (detections and results; 0 for labels).
    """

    frame: np.ndarray
    track_id: np.ndarray
    obj_type: np.ndarray
    truncation: np.ndarray
    occlusion: np.ndarray
    alpha_rad: np.ndarray
    image_box: np.ndarray
    camera_box: np.ndarray
    score: np.ndarray

    def __len__(self) -> int:
        return int(self.frame.shape[0])

    @staticmethod
    def empty() -> KittiRows:
        """Rows of an empty file (a tracker that output nothing, a sequence without results)."""
        return KittiRows(
            frame=np.zeros(0, np.int64),
            track_id=np.zeros(0, np.int64),
            obj_type=np.zeros(0, dtype=object),
            truncation=np.zeros(0),
            occlusion=np.zeros(0, np.int64),
            alpha_rad=np.zeros(0),
            image_box=np.zeros((0, 4)),
            camera_box=np.zeros((0, 7)),
            score=np.zeros(0),
        )

    @staticmethod
    def concat(parts: Sequence[KittiRows]) -> KittiRows:
        """``parts``' rows one after the other (no parts: empty rows)."""
        if not parts:
            return KittiRows.empty()
        return KittiRows(**{f: np.concatenate([getattr(p, f) for p in parts]) for f in KittiRows.__slots__})

    def boxes(self) -> np.ndarray:
        """The 3D boxes as z-up rows of :data:`lastmile.core.box3d.BOX3D_COLUMNS`."""
        return boxes_from_kitti_camera(self.camera_box)

    def select(self, mask: np.ndarray) -> KittiRows:
        """The rows where ``mask`` is true."""
        return KittiRows(
            frame=self.frame[mask],
            track_id=self.track_id[mask],
            obj_type=self.obj_type[mask],
            truncation=self.truncation[mask],
            occlusion=self.occlusion[mask],
            alpha_rad=self.alpha_rad[mask],
            image_box=self.image_box[mask],
            camera_box=self.camera_box[mask],
            score=self.score[mask],
        )


def _parse(path: Path, sep: str | None, n_fields: tuple[int, ...], what: str) -> list[list[str]]:
    if not path.is_file():
        raise ConfigError(f"{what}: expected a file, got {str(path)!r} (missing)")
    try:
        text = path.read_bytes().decode("utf-8")
    except UnicodeDecodeError as exc:
        at_line = path.read_bytes()[: exc.start].count(b"\n") + 1
        raise MessageError(f"{path}:{at_line}: expected {what} as text, got binary data") from None
    rows = []
    for lineno, line in enumerate(text.splitlines(), start=1):
        if not line.strip():
            continue
        fields = [f.strip() for f in line.split(sep)] if sep else line.split()
        if len(fields) not in n_fields:
            raise MessageError(
                f"{path}:{lineno}: expected {' or '.join(map(str, n_fields))} fields, got {len(fields)}"
            )
        rows.append(fields)
    return rows


def _floats(rows: list[list[str]], cols: slice, path: Path) -> np.ndarray:
    try:
        arr = np.array([[float(v) for v in r[cols]] for r in rows], dtype=np.float64)
    except ValueError as exc:
        raise MessageError(f"{path}: expected numbers, got {exc}") from None
    if not np.all(np.isfinite(arr)):
        raise MessageError(f"{path}: expected finite numbers, got NaN or inf")
    return arr


def read_detections(path: Path) -> KittiRows:
    """One PointRCNN detection file (comma separated, 15 fields a line).

    Raises:
        ConfigError: the file is missing.
        MessageError: a line has the wrong number of fields, a non-number, or an unknown type id.
    """
    rows = _parse(path, ",", (15,), "detections")
    num = _floats(rows, slice(0, 15), path).reshape(-1, 15)
    types = num[:, 1].astype(np.int64)
    bad = ~np.isin(types, list(DETECTION_TYPE_IDS))
    if np.any(bad):
        raise MessageError(f"{path}: expected type 1, 2 or 3, got {types[bad][0]}")
    n = num.shape[0]
    return KittiRows(
        frame=num[:, 0].astype(np.int64),
        track_id=np.full(n, -1, np.int64),
        obj_type=np.array([DETECTION_TYPE_IDS[int(t)] for t in types], dtype=object),
        truncation=np.zeros(n),
        occlusion=np.zeros(n, np.int64),
        alpha_rad=num[:, 14].copy(),
        image_box=num[:, 2:6].copy(),
        camera_box=num[:, 7:14].copy(),
        score=num[:, 6].copy(),
    )


def read_labels(path: Path, *, with_score: bool = False) -> KittiRows:
    """A label file (17 fields a line) or, with ``with_score``, a results file (17 or 18 fields).

    Results lines without a score get -1, as the KITTI evaluator does.

    Raises:
        ConfigError: the file is missing.
        MessageError: a line has the wrong number of fields or a non-number.
    """
    rows = _parse(path, None, (17, 18) if with_score else (17,), "labels")
    n = len(rows)
    num = np.zeros((0, 16)) if n == 0 else _floats([[r[0], r[1], *r[3:17]] for r in rows], slice(0, 16), path)
    score = np.array([float(r[17]) if len(r) == 18 else -1.0 for r in rows]) if with_score else np.zeros(n)
    return KittiRows(
        frame=num[:, 0].astype(np.int64),
        track_id=num[:, 1].astype(np.int64),
        obj_type=np.array([r[2] for r in rows], dtype=object),
        truncation=num[:, 2].copy(),
        occlusion=num[:, 3].astype(np.int64),
        alpha_rad=num[:, 4].copy(),
        image_box=num[:, 5:9].copy(),
        camera_box=num[:, 9:16].copy(),
        score=score,
    )


def write_results(path: Path, rows: KittiRows) -> None:
    """Write ``rows`` in the KITTI tracking results format (label format plus a score column)."""
    # Floats are written with repr (shortest round-trip form): an evaluator reading the file sees the
    # very numbers scored in memory (the KITTI sweep is sensitive to the last bit of mean scores).
    lines = []
    for i in range(len(rows)):
        vals = (rows.alpha_rad[i], *rows.image_box[i], *rows.camera_box[i], rows.score[i])
        numbers = " ".join(repr(float(v)) for v in vals)
        lines.append(f"{rows.frame[i]} {rows.track_id[i]} {rows.obj_type[i]} 0 0 {numbers}")
    path.write_text("\n".join(lines) + ("\n" if lines else ""))


def list_sequences(labels_dir: Path) -> list[str]:
    """Sequence names (``<seq>.txt`` stems) under a labels directory, sorted.

    Raises:
        ConfigError: the directory is missing or holds no ``.txt`` file.
    """
    if not labels_dir.is_dir():
        raise ConfigError(f"labels: expected a directory of <seq>.txt, got {str(labels_dir)!r} (missing)")
    seqs = sorted(p.stem for p in labels_dir.glob("*.txt"))
    if not seqs:
        raise ConfigError(f"labels: expected <seq>.txt files, got none in {str(labels_dir)!r}")
    return seqs
