"""KITTI 3D MOT evaluation: CLEAR MOT and sAMOTA/AMOTA per class, as AB3DMOT's evaluator computes them.

Protocol (AB3DMOT ``scripts/KITTI/evaluate.py``, itself the KITTI tracking devkit with 3D IoU):

- per class, ground truth of the class and its neighbour (Car+Van, Pedestrian+Person_sitting) and the
  DontCare regions are loaded; results of the class only;
- per frame, ground truth and results are matched by the Hungarian method on ``1 - IoU3D``, pairs
  below ``min_overlap`` (0.25) are not allowed;
- ignored ground truth (not counted as FN or TP): occlusion > 2, truncation > 0, or the neighbour
  class; ignored results (not counted as FP): unmatched and (image height <= 25 px, or > 50 % of the
  result's image box inside a DontCare box, or of the neighbour class). As in the reference, a result
  once matched in an earlier pass of the threshold sweep stays "valid" (never ignored) afterwards;
- ID switches and fragmentations are counted along each ground-truth trajectory;
- a track's score is the mean of its rows' scores. For sAMOTA/AMOTA, 40 thresholds are taken from the
  scores of the true positives at recalls 1/40 .. 40/40 and the tracks under each threshold are removed:
  sAMOTA = mean of ``clip(1 - (FN + FP + IDS - (1 - r) n_gt) / (r n_gt), 0, 1)``, AMOTA = mean MOTA;
- MOTA, MOTP, IDS, FRAG, FP, FN are reported at the threshold of the sweep with the best MOTA.

Degenerate inputs are handled where the reference fails: identical boxes (robust IoU), empty frames,
and a class absent from a sequence (metrics are NaN, counts 0, instead of a division by zero).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields

import numpy as np
from scipy.optimize import linear_sum_assignment

from lastmile.core.box3d import iou3d_matrix
from lastmile.evaluation.kitti_io import KittiRows

NUM_SAMPLE_POINTS = 41
"""Recall points of the sweep (the first, at recall 0, is dropped: 40 remain)."""

_NEIGHBOUR = {"car": "van", "pedestrian": "person_sitting"}


@dataclass(frozen=True, slots=True, kw_only=True)
class ProtocolConfig:
    """Parameters of the KITTI 3D MOT protocol (defaults are the standard ones).

    ``reference_score_rounding``: the reference overwrites every row's score with its track's mean and
    recomputes the mean from those rows at the next pass of the sweep; the recomputed mean can fall one
    rounding step below the threshold taken from it, which removes the very track that set the
    threshold (its top recall points then score 0). True reproduces that, so the numbers agree with the
    standard evaluator; False compares each track's exact mean.
    """

    min_overlap: float = 0.25
    max_truncation: float = 0.0
    max_occlusion: int = 2
    min_height_px: float = 25.0
    dontcare_overlap: float = 0.5
    reference_score_rounding: bool = True


@dataclass(slots=True)
class _Frame:
    trk_rows: np.ndarray  # indices into the sequence's result rows
    trk_ids: np.ndarray
    iou: np.ndarray  # (n_gt, n_trk)
    cache: dict[bytes, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)


@dataclass(slots=True)
class _Sequence:
    frames: list[_Frame]
    trk_mean_score: np.ndarray  # (R,) mean score of the row's track at the current pass
    row_score: np.ndarray  # (R,) the rows' scores as the reference holds them at the current pass
    track_rows: list[np.ndarray]  # rows of each track, in frame order
    valid: np.ndarray  # (R,) matched in some earlier pass (reference quirk, see module docstring)
    source_rows: np.ndarray  # (R,) each row's index in the results it was prepared from
    # The frames' ground truth end to end (frame order), to count a pass with whole-sequence arrays.
    gt_start: np.ndarray  # (n_frames,) offset of each frame's first labelled object
    gt_ignore: np.ndarray  # (G,)
    trk_ignorable: np.ndarray  # (R,) ignored if unmatched
    trajectories: list[tuple[np.ndarray, list[bool]]]  # per labelled track: its objects, their ignore flags
    matchable: list[int]  # frames with at least one labelled object and one result row


@dataclass(frozen=True, slots=True, kw_only=True)
class ClassResult:
    """Scores of one class. Metrics are fractions (not percent); NaN where the class has no ground truth."""

    samota: float
    amota: float
    amotp: float
    mota: float
    motp: float
    id_switches: int
    fragmentations: int
    fp: int
    fn: int
    tp: int
    n_gt: int
    best_threshold: float

    def as_dict(self) -> dict[str, float | int | None]:
        """JSON-ready dict (NaN becomes None)."""
        out: dict[str, float | int | None] = {}
        for f in fields(self):
            v = getattr(self, f.name)
            out[f.name] = None if isinstance(v, float) and math.isnan(v) else v
        return out


def _class_match(obj_type: np.ndarray, cls: str) -> tuple[np.ndarray, np.ndarray]:
    low = np.array([str(t).lower() for t in obj_type], dtype=object)
    main = low == cls
    neighbour = low == _NEIGHBOUR.get(cls, "\0")
    return main, neighbour


def _area_fraction_inside(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(N, M) fraction of each image box of ``a`` covered by each box of ``b``."""
    x1 = np.maximum(a[:, None, 0], b[None, :, 0])
    y1 = np.maximum(a[:, None, 1], b[None, :, 1])
    x2 = np.minimum(a[:, None, 2], b[None, :, 2])
    y2 = np.minimum(a[:, None, 3], b[None, :, 3])
    w, h = x2 - x1, y2 - y1
    inter = np.where((w > 0) & (h > 0), w * h, 0.0)
    area = ((a[:, 2] - a[:, 0]) * (a[:, 3] - a[:, 1]))[:, None]
    with np.errstate(divide="ignore", invalid="ignore"):
        frac = np.where(area > 0, inter / np.where(area > 0, area, 1.0), 0.0)
    return frac


def _prepare(gt: KittiRows, res: KittiRows, cls: str, n_frames: int, cfg: ProtocolConfig) -> _Sequence:
    g_main, g_nb = _class_match(gt.obj_type, cls)
    g_dc = np.array([str(t).lower() == "dontcare" for t in gt.obj_type], dtype=bool)
    g_keep = (g_main | g_nb) & (gt.track_id != -1)
    r_main, r_nb = _class_match(res.obj_type, cls)
    r_sel = np.nonzero((r_main | r_nb) & (res.frame < n_frames))[0]
    g_boxes = gt.boxes()
    r_boxes = res.boxes()
    r_sel = r_sel[np.argsort(res.frame[r_sel], kind="stable")]  # the reference reads frame by frame
    ids = res.track_id[r_sel]
    track_rows = [np.nonzero(ids == tid)[0] for tid in np.unique(ids)]
    frames = []
    g_by_frame = {f: np.nonzero(g_keep & (gt.frame == f))[0] for f in np.unique(gt.frame[g_keep])}
    dc_by_frame = {f: np.nonzero(g_dc & (gt.frame == f))[0] for f in np.unique(gt.frame[g_dc])}
    local = {f: np.nonzero(res.frame[r_sel] == f)[0] for f in np.unique(res.frame[r_sel])}
    empty = np.zeros(0, np.int64)
    gt_parts: list[np.ndarray] = []
    ignore_parts: list[np.ndarray] = []
    ignorable_parts: list[np.ndarray] = []
    for f in range(n_frames):
        gi = g_by_frame.get(f, empty)
        ti = local.get(f, empty)
        rows = r_sel[ti]
        ignore = (gt.occlusion[gi] > cfg.max_occlusion) | (gt.truncation[gi] > cfg.max_truncation) | g_nb[gi]
        height = np.abs(res.image_box[rows, 1] - res.image_box[rows, 3])
        ignorable = r_nb[rows] | (height <= cfg.min_height_px)
        dci = dc_by_frame.get(f, empty)
        if dci.size and rows.size:
            frac = _area_fraction_inside(res.image_box[rows], gt.image_box[dci])
            ignorable |= np.any(frac > cfg.dontcare_overlap, axis=1)
        frames.append(
            _Frame(trk_rows=ti, trk_ids=res.track_id[rows], iou=iou3d_matrix(g_boxes[gi], r_boxes[rows]))
        )
        gt_parts.append(gi)
        ignore_parts.append(ignore)
        ignorable_parts.append(ignorable)
    # Rows are in frame order, so the frames' rows end to end are the sequence's rows.
    gt_ids = gt.track_id[np.concatenate(gt_parts)] if frames else empty
    gt_ignore = np.concatenate(ignore_parts) if frames else np.zeros(0, bool)
    order = np.argsort(gt_ids, kind="stable")  # each labelled track's objects, in frame order
    cuts = np.flatnonzero(np.diff(gt_ids[order])) + 1
    trajectories = [(idx, gt_ignore[idx].tolist()) for idx in np.split(order, cuts) if idx.size]
    return _Sequence(
        frames=frames,
        trk_mean_score=np.zeros(len(r_sel)),
        row_score=res.score[r_sel].astype(np.float64),
        track_rows=track_rows,
        valid=np.zeros(len(r_sel), dtype=bool),
        source_rows=r_sel,
        gt_start=np.cumsum([0] + [g.shape[0] for g in gt_parts[:-1]]).astype(np.int64),
        gt_ignore=gt_ignore,
        trk_ignorable=np.concatenate(ignorable_parts) if frames else np.zeros(0, bool),
        trajectories=trajectories,
        matchable=[k for k, fr in enumerate(frames) if fr.iou.size],
    )


@dataclass(slots=True)
class _Counts:
    n_gt: int = 0
    tp: int = 0
    fn: int = 0
    fp: int = 0
    id_switches: int = 0
    fragments: int = 0
    total_overlap: float = 0.0
    scores: list[float] = field(default_factory=list)


def _assign(fr: _Frame, active: np.ndarray, min_overlap: float) -> tuple[np.ndarray, np.ndarray]:
    key = active.tobytes()
    hit = fr.cache.get(key)
    if hit is not None:
        return hit
    cols = np.nonzero(active)[0]
    iou = fr.iou[:, cols]
    if iou.size == 0:
        out = (np.zeros(0, np.int64), np.zeros(0, np.int64))
    else:
        allowed = iou >= min_overlap - 1e-12
        cost = np.where(allowed, 1.0 - iou, 1e9)
        r, c = linear_sum_assignment(cost)
        ok = allowed[r, c]
        out = (r[ok], cols[c[ok]])
    fr.cache[key] = out
    return out


def _run(seqs: list[_Sequence], threshold: float, cfg: ProtocolConfig) -> _Counts:
    """One pass of the sweep: the reference's per-frame counts, summed with whole-sequence arrays.

    Only the assignment is per frame. The sums are the reference's per-frame sums regrouped (integers),
    the overlaps are added frame by frame in its order, and a row's ``valid`` flag depends only on its
    own frame's match, so the counts are the reference's exactly.
    """
    cnt = _Counts()
    for seq in seqs:
        _average_scores(seq, cfg.reference_score_rounding)
        keep = ~(seq.trk_mean_score < threshold)
        tracker = np.full(seq.gt_ignore.shape[0], -1, np.int64)  # per labelled object: its track id
        matched: list[np.ndarray] = []
        for k in seq.matchable:
            fr = seq.frames[k]
            gr, tc = _assign(fr, keep[fr.trk_rows], cfg.min_overlap)
            if tc.shape[0]:
                tracker[seq.gt_start[k] + gr] = fr.trk_ids[tc]
                matched.append(fr.trk_rows[tc])
                cnt.total_overlap += float(fr.iou[gr, tc].sum())
        rows = np.concatenate(matched) if matched else np.zeros(0, np.int64)
        seq.valid[rows] = True
        is_matched = tracker >= 0
        ignored_fn = int(np.count_nonzero(~is_matched & seq.gt_ignore))
        ignored_tp = int(np.count_nonzero(is_matched & seq.gt_ignore))
        n_g, tp = seq.gt_ignore.shape[0], rows.shape[0]
        n_ign_trk = int(np.count_nonzero(keep & seq.trk_ignorable & ~seq.valid))
        cnt.n_gt += n_g - ignored_fn - ignored_tp
        cnt.tp += tp
        cnt.fn += n_g - tp - ignored_fn
        cnt.fp += int(np.count_nonzero(keep)) - tp - n_ign_trk
        cnt.scores.extend(seq.trk_mean_score[rows].tolist())
        for idx, ign in seq.trajectories:
            ids, frags = _switches(tracker[idx].tolist(), ign)
            cnt.id_switches += ids
            cnt.fragments += frags
    return cnt


def _average_scores(seq: _Sequence, reference_rounding: bool) -> None:
    """Each row's score becomes its track's mean score (see :class:`ProtocolConfig`)."""
    for rows in seq.track_rows:
        vals = seq.row_score[rows].tolist()
        # Python's left-to-right float sum, as the reference computes it (np.sum is pairwise).
        mean = sum(vals) / float(len(vals))
        seq.trk_mean_score[rows] = mean
        if reference_rounding:
            seq.row_score[rows] = mean


def _switches(g: list[int], ign: list[bool]) -> tuple[int, int]:
    """ID switches and fragmentations along one ground-truth trajectory (the devkit's rules)."""
    if all(ign) or all(t == -1 for t in g):
        return 0, 0
    ids = frags = 0
    last_id = g[0]
    f = 0
    for f in range(1, len(g)):
        if ign[f]:
            last_id = -1
            continue
        if last_id != g[f] and last_id != -1 and g[f] != -1 and g[f - 1] != -1:
            ids += 1
        if f < len(g) - 1 and g[f - 1] != g[f] and last_id != -1 and g[f] != -1 and g[f + 1] != -1:
            frags += 1
        if g[f] != -1:
            last_id = g[f]
    if len(g) > 1 and g[f - 1] != g[f] and last_id != -1 and g[f] != -1 and not ign[f]:
        frags += 1
    return ids, frags


def _thresholds(scores: list[float], num_gt: int) -> tuple[list[float], list[float]]:
    """Score thresholds at recalls 1/40 .. (as ``getThresholds`` of the reference)."""
    if num_gt <= 0:
        return [], []
    s = np.sort(np.asarray(scores, dtype=np.float64))[::-1]
    current = 0.0
    thresholds, recalls = [], []
    for i, score in enumerate(s):
        l_recall = (i + 1) / num_gt
        r_recall = (i + 2) / num_gt if i < len(s) - 1 else l_recall
        if (r_recall - current) < (current - l_recall) and i < len(s) - 1:
            continue
        thresholds.append(float(score))
        recalls.append(current)
        current += 1.0 / (NUM_SAMPLE_POINTS - 1.0)
    return thresholds[1:], recalls[1:]


def _mota(c: _Counts) -> float:
    return 1.0 - (c.fn + c.fp + c.id_switches) / c.n_gt if c.n_gt else math.nan


ROW_MATCHED, ROW_FALSE, ROW_NOT_SCORED = 1, 0, -1
"""Outcomes of :func:`row_outcomes`."""


def row_outcomes(
    gt: KittiRows,
    results: KittiRows,
    cls: str,
    *,
    n_frames: int,
    config: ProtocolConfig | None = None,
) -> np.ndarray:
    """Per result row of one sequence, what the protocol makes of it with no score threshold.

    ``ROW_MATCHED``: assigned to a labelled object (3D IoU >= min_overlap, Hungarian per frame, as the
    sweep's first pass), the rows the protocol counts as true positives and takes its thresholds from;
    this includes objects it does not count as missed either (the neighbour class, too occluded or
    truncated). ``ROW_FALSE``: a counted false positive. ``ROW_NOT_SCORED``:
    another class, a frame beyond ``n_frames``, or an unmatched row the protocol ignores (neighbour class,
    too small, over a DontCare region). Used to calibrate scores on training sequences.
    """
    cfg = config or ProtocolConfig()
    seq = _prepare(gt, results, cls.lower(), n_frames, cfg)
    local = np.full(len(seq.source_rows), ROW_NOT_SCORED, np.int8)
    everything = np.ones(len(seq.source_rows), dtype=bool)
    for fr in seq.frames:
        _, tc = _assign(fr, everything[fr.trk_rows], cfg.min_overlap)
        matched = np.zeros(fr.trk_rows.shape[0], dtype=bool)
        matched[tc] = True
        unmatched = np.where(seq.trk_ignorable[fr.trk_rows], ROW_NOT_SCORED, ROW_FALSE)
        local[fr.trk_rows] = np.where(matched, ROW_MATCHED, unmatched)
    out = np.full(len(results), ROW_NOT_SCORED, np.int8)
    out[seq.source_rows] = local
    return out


def evaluate_class(
    gt: dict[str, KittiRows],
    results: dict[str, KittiRows],
    cls: str,
    *,
    n_frames: dict[str, int] | None = None,
    config: ProtocolConfig | None = None,
) -> ClassResult:
    """Score one class over several sequences.

    Args:
        gt: labels per sequence name.
        results: tracker results per sequence name (a missing sequence counts as no output).
        cls: "Car", "Pedestrian" or "Cyclist" (case-insensitive).
        n_frames: frames per sequence (default: the last labelled frame + 1); results beyond are ignored.
        config: protocol parameters.
    """
    cfg = config or ProtocolConfig()
    c = cls.lower()
    seqs = []
    for name, g in gt.items():
        nf = n_frames[name] if n_frames and name in n_frames else (int(g.frame.max()) + 1 if len(g) else 0)
        r = results.get(name)
        if r is None:
            r = KittiRows.empty()
        seqs.append(_prepare(g, r, c, nf, cfg))
    first = _run(seqs, -10000.0, cfg)  # the reference's "no threshold"
    thresholds, recalls = _thresholds(first.scores, first.tp + first.fn)
    smota_sum = mota_sum = motp_sum = 0.0
    best_mota, best_thr = 0.0, -math.inf
    for thr, rec in zip(thresholds, recalls, strict=True):
        cc = _run(seqs, thr, cfg)
        mota = _mota(cc)
        smota = (
            min(
                1.0,
                max(0.0, 1.0 - (cc.fn + cc.fp + cc.id_switches - (1.0 - rec) * cc.n_gt) / (rec * cc.n_gt)),
            )
            if cc.n_gt and rec > 0
            else 0.0
        )
        smota_sum += smota
        mota_sum += mota if cc.n_gt else 0.0
        motp_sum += cc.total_overlap / cc.tp if cc.tp else 0.0
        if mota > best_mota:
            best_mota, best_thr = mota, thr
    final = _run(seqs, best_thr, cfg)
    denom = NUM_SAMPLE_POINTS - 1
    has_gt = first.n_gt > 0
    return ClassResult(
        samota=smota_sum / denom if has_gt else math.nan,
        amota=mota_sum / denom if has_gt else math.nan,
        amotp=motp_sum / denom if has_gt else math.nan,
        mota=_mota(final),
        motp=final.total_overlap / final.tp if final.tp else (0.0 if has_gt else math.nan),
        id_switches=final.id_switches,
        fragmentations=final.fragments,
        fp=final.fp,
        fn=final.fn,
        tp=final.tp,
        n_gt=final.n_gt,
        best_threshold=best_thr,
    )
