"""Runs specs one after the other in this process (started by tests/test_scale.py with
devices forced by XLA_FLAGS, or as one process of a jax.distributed run).

argv[1]: JSON list of jobs {"spec": {...}, "out": dir, "resume": bool}; or, with
argv[2:] = coordinator process_count process_id, the same jobs under jax.distributed.
Prints one JSON line: the summaries, or {"error": message} for a ConfigError.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path


def main() -> None:
    jobs = json.loads(sys.argv[1])
    if len(sys.argv) > 2:
        from qdrl.placement import initialize_distributed

        coordinator, count, index = sys.argv[2], int(sys.argv[3]), int(sys.argv[4])
        initialize_distributed(coordinator, count, index)
    from qdrl.config import ConfigError
    from qdrl.experiment import run

    out = []
    for job in jobs:
        if job.get("drop_last"):  # resume from the run's first checkpoint
            import shutil

            shutil.rmtree(sorted((Path(job["out"]) / "checkpoints").glob("step_*"))[-1])
        try:
            summary = run(job["spec"], Path(job["out"]), resume=job.get("resume", False), overwrite=not job.get("resume", False))
        except ConfigError as e:
            summary = {"error": str(e)}
        out.append(summary)
    print("RESULT " + json.dumps(out))


if __name__ == "__main__":
    main()
