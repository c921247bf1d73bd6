"""BLAS bounded to one thread where filters run; the bench of the stall runs."""
import json
import os
import subprocess
import sys

from gpf_nav.experiments import blas_bench

PROBE = ("import json; from gpf_nav.blas import limit_blas_threads; from threadpoolctl import threadpool_info; "
         "applied = limit_blas_threads(); "
         "print(json.dumps([applied, [i['num_threads'] for i in threadpool_info() if i['user_api'] == 'blas']]))")


def probe(**env_overrides):
    env = {k: v for k, v in os.environ.items() if k not in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS",
                                                            "MKL_NUM_THREADS")}
    env.update(env_overrides)
    out = subprocess.run([sys.executable, "-c", PROBE], env=env, capture_output=True, text=True, check=True)
    return json.loads(out.stdout)


def test_limit_blas_threads_bounds_every_blas_to_one_thread():
    applied, threads = probe()
    assert applied and threads and all(t == 1 for t in threads)


def test_limit_blas_threads_leaves_a_users_choice_alone():
    applied, threads = probe(OPENBLAS_NUM_THREADS="2")
    assert not applied


def test_blas_bench_reports_every_case(capsys):
    results = blas_bench.main(["--load", "0", "--particles", "1000", "--repeats", "3"])
    assert len(results) == 7 and all(v > 0 for v in results.values())
    assert "BootstrapPF step, BLAS 1" in capsys.readouterr().out
