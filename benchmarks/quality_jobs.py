"""Running the quality benchmark as parallel processes (``quality.py --jobs N``).

Each job is one process of the benchmark script for some (sequence, variants); the jobs of a phase
run ``jobs`` at a time, a phase after the one before (:func:`quality.job_plan` makes the phases).
Every job gets the options of the parent's command line but its own ``--sequences`` and
``--variants`` (:func:`forwarded`), and writes its log under ``<work>/logs/``.
"""

from __future__ import annotations

import logging
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

log = logging.getLogger("quality")


PER_JOB = ("--sequences", "--variants", "--jobs", "--out")  # options each --jobs process gets its own of


def forwarded(argv: list[str]) -> list[str]:
    """``argv`` without the options of :data:`PER_JOB` (``--x v`` or ``--x=v``): what every ``--jobs``
    process shares."""
    out, skip = [], False
    for arg in argv:
        if skip:
            skip = False
        elif arg in PER_JOB:
            skip = True
        elif not arg.startswith(tuple(f"{o}=" for o in PER_JOB)):
            out.append(arg)
    return out


def run_jobs(plan: list[list[tuple[str, list[str]]]], argv: list[str], work: str, jobs: int,
             script: str | Path) -> None:
    """Run each phase's (sequence, variants) jobs as ``jobs`` parallel processes of ``script`` (the
    benchmark) with the options of ``argv`` (:func:`forwarded`; logs under ``<work>/logs/``);
    SystemExit naming the logs of failed jobs."""
    common = forwarded(argv)
    logs = Path(work) / "logs"
    logs.mkdir(parents=True, exist_ok=True)

    def one(job: tuple[str, list[str]]) -> Path | None:
        name, vs = job
        path = logs / f"{name}_{'+'.join(vs)}.log"
        with open(path, "w") as fh:
            rc = subprocess.call([sys.executable, str(script), *common, "--sequences", name, "--variants",
                                  ",".join(vs)], stdout=fh, stderr=subprocess.STDOUT)
        log.info("%s %s: %s", name, ",".join(vs), "done" if rc == 0 else f"failed ({rc}), see {path}")
        return path if rc else None

    for phase in plan:
        with ThreadPoolExecutor(jobs) as ex:
            failed = [p for p in ex.map(one, phase) if p]
        if failed:
            raise SystemExit("quality: jobs failed, see " + ", ".join(map(str, failed)))
