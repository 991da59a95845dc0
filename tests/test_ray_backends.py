"""The Ray backend of every command that offers a process pool gives the serial backend's results.

Skipped without ray (``pip install 'besdrake[cluster]'``). With ``RAY_ADDRESS`` set (CI starts a local
cluster with ``ray start --head`` and sets ``RAY_ADDRESS=auto``) the executors connect to that cluster;
otherwise each test module starts a private local Ray bound to 127.0.0.1.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

ray = pytest.importorskip("ray")

from besdrake.cli import main  # noqa: E402


@pytest.fixture(scope="module", autouse=True)
def _shutdown_ray():
    yield
    ray.shutdown()


@pytest.fixture(scope="module")
def dmp_file(tmp_path_factory):
    from besdrake.imitation import save_dmp
    from besdrake.tasks.throwing.template_base import fitted_default_throw

    base = fitted_default_throw()
    base.execution_time = 2.3
    return save_dmp(base, tmp_path_factory.mktemp("ray") / "throw.dmp.json")


def _refine(dmp_file, out, *backend) -> dict:
    argv = ["refine", str(dmp_file), "--out", str(out), "--episodes", "8", "--popsize", "4", "--runs", "2", "--quiet", "--json", "--no-figures", *backend]
    assert main(argv) == 0
    return json.loads((out / "summary.json").read_text())


def test_refine_ray_matches_serial(dmp_file, tmp_path):
    serial = _refine(dmp_file, tmp_path / "serial", "--backend", "serial")
    on_ray = _refine(dmp_file, tmp_path / "ray", "--backend", "ray", "--workers", "2")
    a, b = serial["runs"][0], on_ray["runs"][0]
    assert a["n_episodes"] == b["n_episodes"] == 8
    assert a["best_distance_m"] == b["best_distance_m"] and a["best_reward"] == b["best_reward"]
    # Every episode's parameters and reward, bit for bit, in both runs (which share the Ray actors, one merged batch per round).
    for k in range(2):
        assert (tmp_path / "serial" / f"run{k}" / "episodes.csv").read_text() == (tmp_path / "ray" / f"run{k}" / "episodes.csv").read_text()


def test_local_ray_keeps_its_dashboard_closed():
    from besdrake.sim.executors import _ray_init_kwargs

    kw = _ray_init_kwargs({}, 2)
    if "RAY_ADDRESS" in __import__("os").environ:
        assert "include_dashboard" not in kw and "num_cpus" not in kw
    else:
        assert kw["include_dashboard"] is False and kw["_node_ip_address"] == "127.0.0.1" and kw["num_cpus"] >= 2
    assert _ray_init_kwargs({"address": "auto", "num_cpus": 2}, 2).get("num_cpus") is None
