"""The speed of a study on this machine (``./rwpend bench`` prints it; pure, no rclpy).

* pure core: samples per CPU second of the loop of :mod:`rwpend_loop.loop` alone
  (:func:`rwpend_loop.loop.run_lockstep`, a 10 s swing-up and catch in ``auto``), and the runs
  per second per core that figure allows for 10 s runs;
* sweep: runs per second per core of the study of ``examples/montecarlo_swingup.yaml`` as a worker
  runs it, its runs stepped together (rwpend_sweep.batch): the CPU time per sample of ``batch``
  runs stepped together over their first ``seconds`` s (the swing-up), times the samples of a run,
  plus each run's set-up and metrics; and, for comparison, its first ``runs`` runs each alone
  (rwpend_sweep.run.run_one: CPU time of each run, the loop plus the metrics).
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


def sweep_speed(runs: int = 3, batch: int = 500, seconds: float = 0.5) -> dict:
    from dataclasses import replace
    from .batch import run_batch
    from .build import prepare
    from .run import run_one
    from .spec import load_study
    study = load_study(EXAMPLE)
    rows, setups = prepare(study)
    succ = study.scenario.success
    cpu = []
    for i in range(min(runs, study.runs)):
        row = run_one(setups[i], succ)
        cpu.append(row['cpu_s'])
    alone = sum(cpu) / len(cpu)
    # the batch: its first seconds, then its first sample alone (the set-up and the metrics)
    n = min(batch, study.runs)
    h = setups[0].model.sample_period
    short = [(i, replace(s, duration=seconds), succ) for i, s in enumerate(setups[:n])]
    t0 = time.process_time()
    run_batch(short)
    t1 = time.process_time()
    run_batch([(i, replace(s, duration=h), w) for i, s, w in short])
    t2 = time.process_time()
    per_sample = ((t1 - t0) - (t2 - t1)) / n / (round(seconds / h) - 1)
    mean = per_sample * (round(study.scenario.duration / h) - 1) + (t2 - t1) / n
    return {'study': study.name, 'runs': n, 'batch': n, 'batch_seconds': seconds,
            'duration_s': study.scenario.duration, 'cpu_s_per_run': mean, 'runs_per_s_per_core': 1.0 / mean,
            'study_1000_runs_s_per_core': 1000 * mean, 'us_per_sample': 1e6 * per_sample,
            'alone_runs': len(cpu), 'alone_cpu_s_per_run': alone, 'alone_runs_per_s_per_core': 1.0 / alone}


def bench(runs: int = 3) -> dict:
    return {'pure_core': pure_core(), 'sweep': sweep_speed(runs)}


def bench_text(r: dict) -> str:
    p, s = r['pure_core'], r['sweep']
    alone = (f", each alone {s['alone_runs_per_s_per_core']:.2f} runs/s per core (CPU {s['alone_cpu_s_per_run']:.3f} s)"
             if 'alone_cpu_s_per_run' in s else '')
    batched = (f"{s['batch']} runs stepped together, {s['us_per_sample']:.1f} us per sample over their first "
               f"{s['batch_seconds']:g} s; " if 'batch' in s else '')
    return (f"sweep: {s['runs_per_s_per_core']:.2f} runs/s per core ({s['study']}, {s['duration_s']:g} s runs, "
            f"{batched}CPU {s['cpu_s_per_run']:.3f} s per run; 1000 runs = {s['study_1000_runs_s_per_core']:.0f} "
            f"core-s{alone}); "
            f"pure core (the loop alone): {p['samples_per_s']:.0f} samples/s = {p['us_per_sample']:.1f} us per "
            f"sample = {p['runs_per_s_per_core']:.2f} runs/s per core")


if __name__ == '__main__':
    print(bench_text(bench()))
