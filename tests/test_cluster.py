"""Power analyses on a Dask cluster (two workers on loopback) and power surfaces (--sweep)."""

from __future__ import annotations

import json
import socket
import warnings

import pandas as pd
import pytest

from conftest import GRID, ROOT, write_experiment


@pytest.fixture(scope="module")
def cluster():
    from distributed import LocalCluster

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        lc = LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                          dashboard_address=None)
    try:
        yield lc.scheduler_address.replace("tcp://", "dask://")
    finally:
        lc.close()


def test_the_power_table_on_two_workers_equals_the_one_process_run(cluster):
    from vtexp.cluster import connect, threads
    from vtexp.simulate import run_power

    one = run_power(GRID, 4, 12, seed=3, workers=1)
    client = connect(cluster)
    try:
        assert threads(client) == 2
        on = run_power(GRID, 4, 12, seed=3, workers=threads(client),
                       executor=client.get_executor())
        # the workers prepared the experiment from its text, checked by SHA-256
        seen = client.run(lambda: sorted(__import__("vtexp.simulate").simulate._SETUPS))
    finally:
        client.close()
    pd.testing.assert_frame_equal(on.table, one.table, check_exact=True)
    pd.testing.assert_frame_equal(on.means, one.means, check_exact=True)
    assert all(len(keys) == 1 for keys in seen.values()) and len(seen) == 2


def test_a_sweep_on_the_cluster_equals_the_sweep_in_one_process(cli, cluster, tmp_path):
    sweep = write_experiment(tmp_path, "participants: [4, 5]\nstudies: 6\n"
                             "repetitions: [1, 2]\n", "sweep.yaml")
    runs = {}
    for name, extra in (("local", ["--workers", "1"]), ("dask", ["--executor", cluster])):
        out = tmp_path / f"{name}.json"
        r = cli("simulate", str(GRID), "--sweep", str(sweep), "--seed", "5", "-q",
                "--out", str(out), *extra)
        assert r.returncode == 0, r.stderr
        runs[name] = (r.stdout, json.loads(out.read_text()))
    (text, local), (text_dask, dask) = runs["local"], runs["dask"]
    assert text == text_dask and local["power"] == dask["power"]
    assert "Power surface (6 studies per point" in text
    assert [ln.split()[:2] for ln in text.splitlines() if ln.strip()[:1].isdigit()] == \
        [["1", "4"], ["1", "5"], ["2", "4"], ["2", "5"]]
    assert len(local["power"]) == 4 * 3 and {p["setting"]["design.repetitions"]
                                             for p in local["points"]} == {1, 2}
    assert len({p["sha256"] for p in local["points"]}) == 2


def test_a_timing_parameter_and_a_csv_surface(cli, tmp_path):
    sweep = write_experiment(tmp_path, "participants: [4]\nstudies: 4\nvary:\n"
                             "  coding.params.vibration_ms: [150, 200]\n", "sweep.yaml")
    out = tmp_path / "surface.csv"
    r = cli("simulate", str(ROOT / "experiments" / "whirlpool.yaml"), "--sweep", str(sweep),
            "-q", "--workers", "1", "--out", str(out))
    assert r.returncode == 0, r.stderr
    t = pd.read_csv(out)
    assert set(t["coding.params.vibration_ms"]) == {150, 200} and (t["participants"] == 4).all()
    assert {"effect", "power", "ci_low", "ci_high", "median_p"} <= set(t.columns)


def test_an_unreachable_scheduler_is_one_message_before_anything_runs(cli):
    with socket.socket() as s:              # a port nothing listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    r = cli("simulate", str(GRID), "--executor", f"dask://127.0.0.1:{port}", "-q")
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert f"cannot reach the Dask scheduler at tcp://127.0.0.1:{port}" in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and "Power" not in r.stdout
    r = cli("simulate", str(GRID), "--executor", "dask://nowhere", "-q")
    assert r.returncode == 2 and "not a scheduler address" in r.stderr


def test_a_worker_refuses_a_text_that_does_not_match_its_hash():
    from dataclasses import replace

    from vtexp.errors import InputError
    from vtexp.simulate import ExperimentSource

    src = ExperimentSource.of(GRID)
    with pytest.raises(InputError, match="damaged on the way"):
        replace(src, text=src.text.replace("repetitions: 3", "repetitions: 2")).setup()


@pytest.mark.parametrize("text, says", [
    ("participants: [1]\n", "participants: a study needs at least 2 participants"),
    ("participants: [4]\nvary:\n  design.bogus: [1]\n",
     "vary.design.bogus: with design.bogus = 1: unknown key"),
    ("participants: [4]\nrepetition: [1]\n", "repetition"),
    ("participants: [4]\nvary:\n  design.repetitions: [0]\n", "with design.repetitions = 0"),
])
def test_a_wrong_sweep_file_is_one_message(cli, tmp_path, text, says):
    sweep = write_experiment(tmp_path, text, "sweep.yaml")
    r = cli("simulate", str(GRID), "--sweep", str(sweep), "-q", "--workers", "1")
    assert r.returncode == 2 and says in r.stderr and "Traceback" not in r.stderr, r.stderr
    assert str(sweep) in r.stderr
