"""Glue to run AB3DMOT (a separate checkout, its own Python) on KITTI PointRCNN detections.

Not part of lastmile and not importable by it: ``benchmarks/tracking_kitti.py --ab3dmot DIR`` runs this
file with AB3DMOT's interpreter. It imports AB3DMOT from DIR (nothing of AB3DMOT is copied here) and
runs its per-class trackers with its published PointRCNN parameters, without ego-motion compensation
(the data has no poses), as ``main.py`` would, writing KITTI results per sequence.

usage: python ab3dmot_driver.py track AB3DMOT_DIR DETECTIONS_DIR OUT_DIR SEQ:NFRAMES ...
       python ab3dmot_driver.py evaluate AB3DMOT_DIR RESULTS_DIR LABELS_DIR SEQ:NFRAMES ...
``track`` prints {"frames", "seconds", "frame_seconds"}; ``evaluate`` runs AB3DMOT's own
``scripts/KITTI/evaluate.py`` (3D IoU 0.25) in a scratch directory and prints its scores per class.
"""

import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
import types
from pathlib import Path


def _stub_helpers():
    """AB3DMOT imports its author's toolbox and OpenCV only for file and drawing helpers; stand-ins."""
    io = types.ModuleType("xinshuo_io")
    io.mkdir_if_missing = lambda p: None
    io.is_path_exists = os.path.exists
    io.fileparts = lambda p: (os.path.dirname(p), *os.path.splitext(os.path.basename(p)))
    io.load_txt_file = lambda p: (Path(p).read_text().splitlines(), 0)
    io.save_txt_file = lambda *a, **k: None
    io.load_list_from_folder = lambda *a, **k: ([], 0)
    misc = types.ModuleType("xinshuo_miscellaneous")
    misc.print_log = lambda *a, **k: None
    misc.get_timestring = lambda: ""
    misc.merge_listoflist = lambda ll, unique=False: [x for sub in ll for x in sub]
    vis = types.ModuleType("xinshuo_visualization")
    vis.random_colors = lambda *a, **k: []
    for m in (io, misc, vis, types.ModuleType("cv2")):
        sys.modules[m.__name__] = m
    import numba

    # numba >= 0.50 refuses AB3DMOT's mixed int/float arrays in @jit functions; numba 0.43 (its pinned
    # version) fell back to object mode there, i.e. plain Python, which the identity decorator reproduces.
    numba.jit = lambda *a, **k: a[0] if a and callable(a[0]) else (lambda f: f)


def track(ab, det_dir, out_dir, seqs):
    sys.path.insert(0, ab)
    _stub_helpers()
    import numpy as np
    from AB3DMOT_libs.io import get_frame_det
    from AB3DMOT_libs.model import AB3DMOT
    from easydict import EasyDict

    cfg = EasyDict(dataset="KITTI", det_name="pointrcnn", vis=False, ego_com=False, affi_pro=True, num_hypo=1)
    id2str = {1: "Pedestrian", 2: "Car", 3: "Cyclist"}
    os.makedirs(out_dir, exist_ok=True)
    lines = {s: [] for s, _ in seqs}
    frame_s = {s: [0.0] * int(n) for s, n in seqs}
    id_start = 1
    for cat in ("Car", "Pedestrian", "Cyclist"):
        for seq, nf in seqs:
            dets = np.loadtxt(os.path.join(det_dir, "pointrcnn_" + cat, seq + ".txt"), delimiter=",", ndmin=2)
            if dets.shape[0] == 0:
                continue
            trk = AB3DMOT(cfg, cat, calib=None, oxts=None, ID_init=id_start)
            for frame in range(int(nf)):
                d = get_frame_det(dets, frame)
                t0 = time.perf_counter()
                res, _ = trk.track(d, frame, seq)
                frame_s[seq][frame] += time.perf_counter() - t0
                for r in res[0]:
                    r = r.reshape(-1)
                    b, tid, ori, typ, b2, conf = r[0:7], int(r[7]), r[8], id2str[int(r[9])], r[10:14], r[14]
                    vals = " ".join(f"{v:f}" for v in (ori, *b2, *b, conf))
                    lines[seq].append(f"{frame} {tid} {typ} 0 0 {vals}")
            id_start = max(id_start, trk.ID_count[0])
    for seq, _ in seqs:
        with open(os.path.join(out_dir, seq + ".txt"), "w") as fh:
            fh.write("\n".join(lines[seq]) + ("\n" if lines[seq] else ""))
    per_frame = [t for s, _ in seqs for t in frame_s[s]]
    print(json.dumps({"frames": len(per_frame), "seconds": sum(per_frame), "frame_seconds": per_frame}))


def evaluate(ab, res, labels, seqs):
    root = tempfile.mkdtemp(prefix="ab3dmot_eval_")
    kitti = os.path.join(root, "scripts", "KITTI")
    os.makedirs(kitti)
    for f in ("evaluate.py", "munkres.py", "mailpy.py"):
        shutil.copy(os.path.join(ab, "scripts", "KITTI", f), kitti)
    with open(os.path.join(kitti, "evaluate_tracking.seqmap.val"), "w") as fh:
        fh.write("".join(f"{s} empty 000000 {int(n) - 1:06d}\n" for s, n in seqs))
    os.symlink(os.path.abspath(labels), os.path.join(kitti, "label"))
    data = os.path.join(root, "results", "KITTI", "sha", "data_0")
    shutil.copytree(res, data)  # a copy, not a link: the script writes its summaries next to it
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([root, kitti, ab]), MPLBACKEND="Agg")
    here = os.path.dirname(os.path.abspath(__file__))
    code = (
        f"import sys; sys.path.insert(0, {here!r}); import ab3dmot_driver as d; d._stub_helpers(); "
        "import runpy; "
        "sys.argv = ['evaluate.py', 'sha', '1', '3D', '0.25']; runpy.run_path('scripts/KITTI/evaluate.py', "
        "run_name='__main__')"
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=root, env=env, capture_output=True, text=True)
    if out.returncode:
        sys.stderr.write(out.stderr[-3000:])
        sys.exit(1)
    scores = {}
    for cls in ("car", "pedestrian", "cyclist"):
        p = os.path.join(root, "results", "KITTI", "sha", f"summary_{cls}_average_eval3D.txt")
        if not os.path.exists(p):
            continue
        text = Path(p).read_text()
        m = re.search(r"sAMOTA\s+AMOTA\s+AMOTP\s*\n\s*(\S+)\s+(\S+)\s+(\S+)", text)
        best = text.split("best results with single threshold")[-1]

        def grab(name, best=best):
            mm = re.search(re.escape(name) + r"\s+([-\d.e+]+)", best)
            return float(mm.group(1)) if mm else None

        scores[cls.capitalize()] = {
            "samota": float(m.group(1)),
            "amota": float(m.group(2)),
            "mota": grab("Multiple Object Tracking Accuracy (MOTA)"),
            "motp": grab("Multiple Object Tracking Precision (MOTP)"),
            "id_switches": grab("ID-switches"),
            "fragmentations": grab("Fragmentations"),
            "fp": grab("False Positives"),
            "fn": grab("False Negatives"),
        }
    shutil.rmtree(root)
    print(json.dumps(scores))


if __name__ == "__main__":
    cmd, ab, a, b = sys.argv[1:5]
    seq_args = [s.split(":") for s in sys.argv[5:]]
    (track if cmd == "track" else evaluate)(ab, a, b, seq_args)
