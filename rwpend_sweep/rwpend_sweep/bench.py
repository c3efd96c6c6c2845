"""The speed of a study on this machine (``./rwpend bench`` prints it; pure, no rclpy).

* pure core: samples per CPU second of the loop of :mod:`rwpend_loop.loop` alone
  (:func:`rwpend_loop.loop.run_lockstep`, a 10 s swing-up and catch in ``auto``), and the runs
  per second per core that figure allows for 10 s runs;
* sweep: runs per second per core of the study of ``examples/montecarlo_swingup.yaml`` (its first
  ``runs`` runs, CPU time of each run: the loop, as the nodes build it, plus the metrics).
"""
from __future__ import annotations

import time
from pathlib import Path

EXAMPLE = Path(__file__).resolve().parents[1] / 'examples' / 'montecarlo_swingup.yaml'


def pure_core(duration: float = 10.0) -> dict:
    from rwpend_loop.loop import run_lockstep
    from .build import prepare
    from .run import build_loop
    from .spec import study_from_dict
    s = study_from_dict({'scenario': {'mode': 'auto', 'duration': duration}})
    _, setups = prepare(s)
    loop = build_loop(setups[0])
    n = int(round(duration / setups[0].model.sample_period))
    t0 = time.process_time()
    run_lockstep(loop, n)
    cpu = time.process_time() - t0
    return {'samples': n, 'cpu_s': cpu, 'samples_per_s': n / cpu, 'us_per_sample': 1e6 * cpu / n,
            'runs_per_s_per_core': 1.0 / cpu}


def sweep_speed(runs: int = 3) -> dict:
    from .build import prepare
    from .run import run_one
    from .spec import load_study
    study = load_study(EXAMPLE)
    rows, setups = prepare(study)
    cpu = []
    for i in range(min(runs, study.runs)):
        row = run_one(setups[i], study.scenario.success)
        cpu.append(row['cpu_s'])
    mean = sum(cpu) / len(cpu)
    return {'study': study.name, 'runs': len(cpu), 'duration_s': study.scenario.duration,
            'cpu_s_per_run': mean, 'runs_per_s_per_core': 1.0 / mean,
            'study_1000_runs_s_per_core': 1000 * mean}


def bench(runs: int = 3) -> dict:
    return {'pure_core': pure_core(), 'sweep': sweep_speed(runs)}


def bench_text(r: dict) -> str:
    p, s = r['pure_core'], r['sweep']
    return (f"sweep: {s['runs_per_s_per_core']:.2f} runs/s per core ({s['study']}, {s['duration_s']:g} s runs, "
            f"CPU {s['cpu_s_per_run']:.3f} s per run; 1000 runs = {s['study_1000_runs_s_per_core']:.0f} core-s); "
            f"pure core (the loop alone): {p['samples_per_s']:.0f} samples/s = {p['us_per_sample']:.1f} us per "
            f"sample = {p['runs_per_s_per_core']:.2f} runs/s per core")


if __name__ == '__main__':
    print(bench_text(bench()))
