"""Child process for the crash tests: records a synthetic stack stream, then raises, or waits to be killed."""

from __future__ import annotations

import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from lastmile.recorder.black_box import BlackBox, BlackBoxConfig, install_sigterm_handler
from tests.recorder.stream import record_ticks


def main() -> None:
    mode, out = sys.argv[1], Path(sys.argv[2])
    spool = 5_000_000 if mode == "sigkill" else None
    bb = BlackBox(BlackBoxConfig(out_dir=out, spool_chunk_us=spool, compression="lz4"))
    if mode == "sigterm":
        install_sigterm_handler(bb)
    try:
        for _ in record_ticks(bb, 0, 4000, lidar_points=100):  # 40 s of loop time
            pass
        if mode == "raise":
            raise RuntimeError("planner blew up mid-run")
        bb.flush()
        print("ready", flush=True)
        tick = 4000
        while True:  # keep running (and recording) until a signal ends the process
            for _ in record_ticks(bb, tick, 10, lidar_points=100):
                pass
            tick += 10
            time.sleep(0.005)
    except Exception as exc:
        # What the runner does on an unhandled exception in the loop: dump synchronously, then re-raise.
        bb.dump("crash", reason=f"{type(exc).__name__}: {exc}")
        raise


if __name__ == "__main__":
    main()
